#version 450
// gather.comp — the gather (gather.glsl) in the exact segment form with endless beams (the default).
#extension GL_GOOGLE_include_directive : require
#define NS_GATHER_FORM NS_GATHER_MODE_EXACT
#define NS_BOUNDED_BEAMS 0
#include "gather.glsl"
