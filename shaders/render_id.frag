#version 460
// Object-id pipeline of src/cullpipe/render: writes the object's colour unshaded, which the id pass
// sets to its id + 1 in 24 bits (8 per channel: exact in an 8-bit UNORM target), 0 the background.
layout(location = 0) in vec3 world_position;
layout(location = 1) flat in vec3 color;
layout(location = 0) out vec4 out_color;

void main() { out_color = vec4(color, 1.0); }
