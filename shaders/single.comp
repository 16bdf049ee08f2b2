#version 450
// single.comp — single scattering along camera segments (single.glsl): the default form,
// which connects through the face that the straight line towards the light crosses.
#extension GL_GOOGLE_include_directive : require
#define NS_SINGLE_BOX_FACES 0
#include "single.glsl"
