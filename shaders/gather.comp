#version 450
// gather.comp — placeholder until its stage lands (render/scatter.h names the owner): a valid
// pipeline so that the context can create and warm every pipeline from one table.
layout(local_size_x = 64) in;
void main()
{
}
