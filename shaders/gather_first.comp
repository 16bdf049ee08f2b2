#version 450
// gather_first.comp — the gather (gather.glsl) of the boundary sources' blurred first order,
// computed per source and segment (first_order) instead of read from a table.
#extension GL_GOOGLE_include_directive : require
#define NS_GATHER_FORM NS_GATHER_MODE_FIRST
#define NS_BOUNDED_BEAMS 0
#define NS_GATHER_FIRST_ORDER 1 // the preprocessor cannot read NS_GATHER_FORM's constant
#include "gather.glsl"
