#version 450
// Placeholder so the shader pipeline builds before the real shaders land.
layout(local_size_x = 1) in;
void main() {}
