#version 450
// gather_exact_first.comp — the default gather (gather.glsl: exact segment form, endless beams)
// of boundary sources that read the blurred first order besides their tables: first_order
// computed in the same walk over the sources.
#extension GL_GOOGLE_include_directive : require
#define NS_GATHER_FORM NS_GATHER_MODE_EXACT
#define NS_BOUNDED_BEAMS 0
#define NS_GATHER_FIRST_ORDER 1 // the preprocessor cannot read NS_GATHER_FORM's constant
#include "gather.glsl"
