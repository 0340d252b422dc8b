#version 450
// AR alpha layer: the person as premultiplied linear RGBA, alpha clamped to [0, 1] and colour to [0, alpha]
// (compose::compose_ar), so a compositor never sees an invalid premultiplied pixel.
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;

layout(std430, set = 0, binding = 4) readonly buffer Person { vec4 person[]; };
layout(std430, set = 0, binding = 10) buffer Out { vec4 result[]; };

void main() {
    uint width = uint(frame.target.info.y);
    uint height = uint(frame.target.info.z);
    uvec2 id = gl_GlobalInvocationID.xy;
    if (id.x >= width || id.y >= height) {
        return;
    }
    uint index = id.y * width + id.x;
    vec4 p = person[index];
    float a = clamp(p.a, 0.0, 1.0);
    result[index] = vec4(clamp(p.rgb, vec3(0.0), vec3(a)), a);
}
