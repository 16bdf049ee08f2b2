#version 450
// gather_paper.comp — the gather (gather.glsl) in the paper's 5-mfp form (render.accumulation "paper").
#extension GL_GOOGLE_include_directive : require
#define NS_GATHER_FORM NS_GATHER_MODE_PAPER
#define NS_BOUNDED_BEAMS 0
#include "gather.glsl"
