#version 450
// Push-pull hole filling, pull step (warp.rs push_pull): each coarse pixel is the coverage-weighted mean of its
// (up to) four finer pixels, its weight capped at 1.
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;

layout(std430, set = 0, binding = 15) buffer Pyramid { vec4 pyramid[]; };

void main() {
    uvec2 id = gl_GlobalInvocationID.xy;
    if (id.x >= level.dst_width || id.y >= level.dst_height) {
        return;
    }
    vec4 s = vec4(0.0);
    for (uint k = 0u; k < 4u; k++) {
        uint c = 2u * id.x + (k & 1u);
        uint r = 2u * id.y + (k >> 1u);
        if (c < level.src_width && r < level.src_height) {
            s += pyramid[level.src_offset + r * level.src_width + c];
        }
    }
    vec4 result = vec4(0.0);
    if (s.w > 0.0) {
        float w = min(s.w, 1.0);
        result = vec4(s.rgb / s.w * w, w);
    }
    pyramid[level.dst_offset + id.y * level.dst_width + id.x] = result;
}
