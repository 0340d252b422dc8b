#version 450
// Spatial fusion (paper Eq. 8, src/pipeline/fusion.rs): where the current pixel's surface point was visible in
// the previous view (Eq. 9 against the previous depth), blend un-premultiplied colours with the previous
// output warped into this view: (1 - w) * I_t + w * I_pre, w = frame.params.y; elsewhere I_t.
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;

layout(std430, set = 0, binding = 1) readonly buffer Geometry { vec4 geometry[]; };
layout(std430, set = 0, binding = 2) readonly buffer Color { vec4 color[]; };
layout(std430, set = 0, binding = 4) buffer Person { vec4 person[]; };
layout(std430, set = 0, binding = 5) readonly buffer PrevPerson { vec4 prev_person[]; };
layout(std430, set = 0, binding = 6) readonly buffer PrevGeometry { vec4 prev_geometry[]; };
layout(std430, set = 0, binding = 14) readonly buffer Current { vec4 current[]; };

vec4 prev_fetch(int c, int r, int w, int h) {
    if (c < 0 || r < 0 || c >= w || r >= h) {
        return vec4(0.0);
    }
    return prev_person[r * w + c];
}

void main() {
    uint width = uint(frame.target.info.y);
    uint height = uint(frame.target.info.z);
    uvec2 id = gl_GlobalInvocationID.xy;
    if (id.x >= width || id.y >= height) {
        return;
    }
    uint index = id.y * width + id.x;
    vec4 o = current[index];
    float wp = frame.params.y;
    if (frame.flags.x == 0u || wp <= 0.0 || color[index].w <= 0.5 || o.w <= 0.0) {
        person[index] = o;
        return;
    }
    vec3 world = unproject(frame.target, vec2(id) + 0.5, geometry[index].w);
    vec4 q = project(frame.previous, world);
    int pw = int(frame.previous.info.y);
    int ph = int(frame.previous.info.z);
    if (q.w < 0.5 || !(abs(q.x) < 1e30 && abs(q.y) < 1e30 && abs(q.z) < 1e30)) {
        person[index] = o;
        return;
    }
    // Eq. 9 visibility in the previous view (nearest lookup of its depth).
    float x = floor(q.x);
    float y = floor(q.y);
    bool visible = false;
    if (x >= 0.0 && y >= 0.0 && x < float(pw) && y < float(ph)) {
        float d = prev_geometry[int(y) * pw + int(x)].w;
        if (d > -1e29) {
            float scale = frame.previous.info.x < 0.5 ? 1.0 + min(q.z, d) : min(-q.z, -d);
            visible = scale > 0.0 && abs(q.z - d) < frame.params.z * scale;
        }
    }
    if (!visible) {
        person[index] = o;
        return;
    }
    // Bilinear sample of the previous output, zero outside (buffer::sample_bilinear).
    float fx = q.x - 0.5;
    float fy = q.y - 0.5;
    float x0 = floor(fx);
    float y0 = floor(fy);
    float tx = fx - x0;
    float ty = fy - y0;
    int c0 = int(x0);
    int r0 = int(y0);
    vec4 top = prev_fetch(c0, r0, pw, ph) * (1.0 - tx) + prev_fetch(c0 + 1, r0, pw, ph) * tx;
    vec4 bottom = prev_fetch(c0, r0 + 1, pw, ph) * (1.0 - tx) + prev_fetch(c0 + 1, r0 + 1, pw, ph) * tx;
    vec4 p = top * (1.0 - ty) + bottom * ty;
    if (!(p.w >= 0.5)) {
        person[index] = o;
        return;
    }
    vec3 pre = p.rgb / p.w;
    vec3 cur = o.rgb / o.w;
    vec3 blended = clamp(cur * (1.0 - wp) + pre * wp, vec3(0.0), vec3(1.0));
    person[index] = vec4(blended * o.w, o.w);
}
