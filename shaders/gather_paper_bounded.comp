#version 450
// gather_paper_bounded.comp — the gather (gather.glsl) in the paper's 5-mfp form with bounded beams.
#extension GL_GOOGLE_include_directive : require
#define NS_GATHER_FORM NS_GATHER_MODE_PAPER
#define NS_BOUNDED_BEAMS 1
#include "gather.glsl"
