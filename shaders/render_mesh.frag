#version 460
// Flat shading from the screen-space derivatives of the world position (no normals needed):
// ambient plus a two-sided directional light.
layout(location = 0) in vec3 world_position;
layout(location = 1) flat in vec3 color;
layout(location = 0) out vec4 out_color;

void main() {
  vec3 n = cross(dFdx(world_position), dFdy(world_position));
  float len = length(n);
  float light = len > 0.0 ? 0.35 + 0.65 * abs(dot(n / len, normalize(vec3(0.4, 0.8, 0.45)))) : 1.0;
  out_color = vec4(color * light, 1.0);
}
