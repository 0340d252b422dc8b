#version 450
// VR compositing over an equirectangular panorama (SPEC.md, src/io/environment.rs, src/compose):
// out = person.rgb + (1 - person.a) * env(ray of the viewer camera), bilinear, horizontal wrap, pole-aware rows.
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;

layout(std430, set = 0, binding = 4) readonly buffer Person { vec4 person[]; };
// Environment texels as packed half floats: (r, g), (b, 0).
layout(std430, set = 0, binding = 9) readonly buffer Env { uvec2 env[]; };
layout(std430, set = 0, binding = 10) buffer Out { vec4 result[]; };

vec3 env_texel(int cx, int cy, int w, int h) {
    // Across a pole the row reflects and the column moves half a turn (as the CPU reference).
    if (cy < 0) {
        cy = -1 - cy;
        cx += w / 2;
    } else if (cy >= h) {
        cy = 2 * h - 1 - cy;
        cx += w / 2;
    }
    cy = clamp(cy, 0, h - 1);
    cx = cx % w;
    if (cx < 0) {
        cx += w;
    }
    uvec2 t = env[cy * w + cx];
    return vec3(unpackHalf2x16(t.x), unpackHalf2x16(t.y).x);
}

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
    vec3 fg = max(p.rgb, vec3(0.0));
    if (a >= 1.0) {
        result[index] = vec4(fg, 1.0);
        return;
    }
    vec3 d = ray_direction(frame.viewer, vec2(id) + 0.5);
    float cy = cos(frame.params.x);
    float sy = sin(frame.params.x);
    // The panorama turned by yaw about +y (direction rotated by -yaw), as environment::direction_to_uv.
    float dx = cy * d.x + sy * d.z;
    float dz = -sy * d.x + cy * d.z;
    const float PI = 3.14159265358979;
    float u = 0.5 + atan(dx, -dz) / (2.0 * PI);
    float v = acos(clamp(d.y, -1.0, 1.0)) / PI;
    int ew = int(frame.sizes.x);
    int eh = int(frame.sizes.y);
    float x = u * float(ew) - 0.5;
    float y = v * float(eh) - 0.5;
    float x0f = floor(x);
    float y0f = floor(y);
    float fx = x - x0f;
    float fy = y - y0f;
    int x0 = int(x0f);
    int y0 = int(y0f);
    vec3 top = env_texel(x0, y0, ew, eh) * (1.0 - fx) + env_texel(x0 + 1, y0, ew, eh) * fx;
    vec3 bottom = env_texel(x0, y0 + 1, ew, eh) * (1.0 - fx) + env_texel(x0 + 1, y0 + 1, ew, eh) * fx;
    vec3 e = top * (1.0 - fy) + bottom * fy;
    result[index] = vec4(fg + e * (1.0 - a), 1.0);
}
