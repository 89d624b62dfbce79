#version 460
// Primitive-id pipeline of src/cullpipe/render: writes the triangle's index within its draw + 1 in
// 32 bits (8 per channel of an 8-bit UNORM target, exact), 0 the background. Drawn with the
// unculled draws, one per object, after the object-id pass: each pixel's (object, triangle).
// Reading gl_PrimitiveID in a fragment shader needs the geometryShader feature.
layout(location = 0) in vec3 world_position;  // (the mesh pipeline's interface, unused here)
layout(location = 1) flat in vec3 color;
layout(location = 0) out vec4 out_color;

void main() {
  uint id = uint(gl_PrimitiveID) + 1u;
  out_color = vec4(float(id & 255u), float(id >> 8 & 255u), float(id >> 16 & 255u), float(id >> 24)) / 255.0;
}
