#version 450
// Linear float output -> packed 8-bit sRGB for the window (copied into the swapchain image). AR layers are
// shown over mid grey, standing in for passthrough. The text overlay (src/gpu/overlay.rs: one byte per pixel of
// a top-left rectangle, 1 = dark plate, 2 = white letter) is blended here, so it is only in presented images.
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;

layout(std430, set = 0, binding = 10) readonly buffer Out { vec4 result[]; };
layout(std430, set = 0, binding = 13) buffer Encoded { uint encoded[]; };
layout(std430, set = 0, binding = 16) readonly buffer Overlay { uint overlay[]; };

float to_srgb(float v) {
    v = clamp(v, 0.0, 1.0);
    return v <= 0.0031308 ? v * 12.92 : 1.055 * pow(v, 1.0 / 2.4) - 0.055;
}

void main() {
    uint width = uint(frame.target.info.y);
    uint height = uint(frame.target.info.z);
    uvec2 id = gl_GlobalInvocationID.xy;
    if (id.x >= width || id.y >= height) {
        return;
    }
    uint index = id.y * width + id.x;
    vec4 p = result[index];
    vec3 rgb = p.rgb;
    if (frame.output_format.y != 0u) {
        rgb = rgb + (1.0 - clamp(p.a, 0.0, 1.0)) * vec3(0.2159);
    }
    vec3 s = vec3(to_srgb(rgb.r), to_srgb(rgb.g), to_srgb(rgb.b));
    uvec2 ov = frame.output_format.zw;
    if (id.x < ov.x && id.y < ov.y) {
        uint k = id.y * ov.x + id.x;
        uint v = (overlay[k >> 2u] >> ((k & 3u) * 8u)) & 255u;
        if (v == 1u) {
            s = s * 0.3;
        } else if (v == 2u) {
            s = vec3(1.0);
        }
    }
    if (frame.output_format.x != 0u) {
        s = s.bgr;
    }
    encoded[index] = packUnorm4x8(vec4(s, 1.0));
}
