#version 460
// Mesh pipeline of src/cullpipe/render: positions from the shared vertex buffer, the object's model
// matrix and colour from the object buffer at gl_InstanceIndex (each draw's firstInstance is
// its object id), so culled and unculled draws of an object are the same draw.
#extension GL_GOOGLE_include_directive : require

#include "cullpipe/gpu/cull_types.h"

layout(location = 0) in vec3 position;
layout(std430, set = 0, binding = 0) readonly buffer Objects { RenderObject objects[]; };
layout(push_constant, std430) uniform Push { RenderParams params; };

layout(location = 0) out vec3 world_position;
layout(location = 1) flat out vec3 color;

void main() {
  RenderObject o = objects[gl_InstanceIndex];
  vec4 w = o.model * vec4(position, 1.0);
  world_position = w.xyz;
  color = o.color.rgb;
  gl_Position = params.view_proj * w;
}
