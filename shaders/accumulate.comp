#version 450
// accumulate.comp — the accumulation (accumulate.glsl): the three channels.
#extension GL_GOOGLE_include_directive : require
#define NS_ACCUMULATE_SECOND 0
#include "accumulate.glsl"
