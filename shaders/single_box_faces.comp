#version 450
// single_box_faces.comp — single scattering (single.glsl) in a scene with a box of a refracting
// medium: light reaches a point in a box through each face that sees the light. Its own
// shader so that other scenes do not carry that code: in the default form it made the bench
// bunny's single scattering 5% slower (render/single.c picks the form).
#extension GL_GOOGLE_include_directive : require
#define NS_SINGLE_BOX_FACES 1
#include "single.glsl"
