#version 450
// Push-pull hole filling, push step (warp.rs push_pull): finer pixels with weight < 1 are completed by the
// bilinearly upsampled (clamp-to-edge) coarser level.
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;

layout(std430, set = 0, binding = 15) buffer Pyramid { vec4 pyramid[]; };

vec4 coarse(uint c, uint r) {
    return pyramid[level.src_offset + r * level.src_width + c];
}

void main() {
    uvec2 id = gl_GlobalInvocationID.xy;
    if (id.x >= level.dst_width || id.y >= level.dst_height) {
        return;
    }
    uint index = level.dst_offset + id.y * level.dst_width + id.x;
    vec4 px = pyramid[index];
    if (px.w >= 1.0) {
        return;
    }
    float x = (float(id.x) + 0.5) * 0.5;
    float y = (float(id.y) + 0.5) * 0.5;
    float fx = clamp(x - 0.5, 0.0, float(level.src_width - 1u));
    float fy = clamp(y - 0.5, 0.0, float(level.src_height - 1u));
    uint x0 = uint(floor(fx));
    uint y0 = uint(floor(fy));
    uint x1 = min(x0 + 1u, level.src_width - 1u);
    uint y1 = min(y0 + 1u, level.src_height - 1u);
    float tx = fx - float(x0);
    float ty = fy - float(y0);
    vec4 top = coarse(x0, y0) * (1.0 - tx) + coarse(x1, y0) * tx;
    vec4 bottom = coarse(x0, y1) * (1.0 - tx) + coarse(x1, y1) * tx;
    vec4 up = top * (1.0 - ty) + bottom * ty;
    vec3 up_rgb = up.w > 0.0 ? up.rgb / up.w : vec3(0.0);
    pyramid[index] = vec4(px.rgb + up_rgb * (1.0 - px.w), 1.0);
}
