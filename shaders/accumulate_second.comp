#version 450
// accumulate_second.comp — the accumulation (accumulate.glsl) with the second three walked
// beside the three channels (accumulate_shared.h).
#extension GL_GOOGLE_include_directive : require
#define NS_ACCUMULATE_SECOND 1
#include "accumulate.glsl"
