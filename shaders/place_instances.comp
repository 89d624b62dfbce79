#version 460
// Places instances in the world: for each entry of the list (an object's transform, mesh and
// slot), its mesh's local volume under its transform (shared/instance.glsl, bit for bit
// src/cullpipe/geom/instance.cpp), written into the bounds buffer the culling passes read at its
// slot, and for boxes their centre and settling bound. An OBB's entry carries its box, placed
// by the host, which is copied to its slot. Only the objects that changed are listed,
// each once; the others keep the volumes placed before. The list is read in order and only the
// outputs are scattered.
#extension GL_GOOGLE_include_directive : require

#include "cullpipe/gpu/cull_types.h"
#include "shared/instance.glsl"

layout(local_size_x = PLACE_GROUP_SIZE) in;
layout(constant_id = 0) const uint BV_KIND = BV_KIND_AABB;

layout(set = 0, binding = PLACE_BINDING_LIST) uniform usamplerBuffer list;
layout(set = 0, binding = PLACE_BINDING_MESHES) uniform usamplerBuffer meshes;
layout(std430, set = 0, binding = PLACE_BINDING_BOUNDS) writeonly buffer Bounds { vec4 bound_words[]; };
layout(std430, set = 0, binding = PLACE_BINDING_CENTRES) writeonly buffer Centres { vec4 centres[]; };
layout(push_constant) uniform Push { PlaceParams params; };

vec4 word(usamplerBuffer b, uint i) { return uintBitsToFloat(texelFetch(b, int(i))); }

// A box's settling bound (src/cullpipe/geom/plane_bounds.hpp) from float arithmetic, for any
// device: |E|_1 stands for |E| and the factors cover every rounding (docs/numerics.md, Instance
// volumes). Not compared with anything bit for bit: any value at least the proof's is as good.
float box_bound(vec3 c, vec3 e) {
  precise float e1 = (abs(e.x) + abs(e.y)) + abs(e.z);
  precise float c1 = (abs(c.x) + abs(c.y)) + abs(c.z);
  precise float b = (e1 + e1 * (1.0 / 16384.0)) + (c1 + e1) * (1.0 / 131072.0) + uintBitsToFloat(0x0d800000u);  // 2^-100
  precise float magnitude = c1 + e1;
  // On the bits (a NaN or infinite magnitude has bits above 2^120's): NaN settles nothing.
  return floatBitsToUint(magnitude) <= 0x7b800000u ? b : uintBitsToFloat(0x7fc00000u);
}

void main() {
  uint k = params.first + gl_GlobalInvocationID.x;
  if (k >= params.count) return;
  if (BV_KIND == BV_KIND_OBB) {  // placed on the host: copied to its slot, bits as they are
    uint base = k * OBB_ENTRY_TEXELS, slot = texelFetch(list, int(base + 4u)).z;
    for (uint j = 0u; j < 4u; ++j) bound_words[4u * slot + j] = word(list, base + j);
    return;
  }
  uint base = k * INSTANCE_TEXELS;
  vec4 rows[3] = vec4[3](word(list, base), word(list, base + 1u), word(list, base + 2u));
  uvec4 info = texelFetch(list, int(base + 3u));
  uint slot = info.z;
  if (BV_KIND == BV_KIND_AABB) {
    vec3 wmin, wmax;
    instance_aabb(rows, word(meshes, 2u * info.x).xyz, word(meshes, 2u * info.x + 1u).xyz, wmin, wmax);
    bound_words[2u * slot] = vec4(wmin, 0.0);
    bound_words[2u * slot + 1u] = vec4(wmax, 0.0);
    // The centre as the host computes it for world boxes: (min + max) / 2 rounded to a float.
    precise vec3 centre = (wmin + wmax) * 0.5;
    precise vec3 half_extent = (wmax - wmin) * 0.5;
    centres[slot] = vec4(centre, box_bound(centre, half_extent));
  } else {
    vec4 local = word(meshes, info.x);
    bound_words[slot] = instance_sphere(rows, local.xyz, local.w, uintBitsToFloat(info.y));
  }
}
