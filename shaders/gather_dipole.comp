#version 450
// gather_dipole.comp — the gather (gather.glsl) in the dipole (method dipole).
#extension GL_GOOGLE_include_directive : require
#define NS_GATHER_FORM NS_GATHER_MODE_DIPOLE
#define NS_BOUNDED_BEAMS 0
#include "gather.glsl"
