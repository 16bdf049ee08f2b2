#version 450
// gather_bounded.comp — the gather (gather.glsl) in the exact segment form with bounded beams (render.vrl_beams).
#extension GL_GOOGLE_include_directive : require
#define NS_GATHER_FORM NS_GATHER_MODE_EXACT
#define NS_BOUNDED_BEAMS 1
#include "gather.glsl"
