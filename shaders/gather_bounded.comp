#version 450
// gather_bounded.comp — the gather (gather.glsl) with bounded beams (render.vrl_beams "bounded").
#extension GL_GOOGLE_include_directive : require
#define NS_BOUNDED_BEAMS 1
#include "gather.glsl"
