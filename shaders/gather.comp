#version 450
// gather.comp — the gather (gather.glsl) with endless beams (the paper; the default).
#extension GL_GOOGLE_include_directive : require
#define NS_BOUNDED_BEAMS 0
#include "gather.glsl"
