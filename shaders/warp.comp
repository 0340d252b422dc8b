#version 450
// Geometric warp (src/pipeline/warp.rs, render_from_flow, first half): covered target pixels with a flow take the
// source colour at the flow — when visible, or always with the mirrored-front and back fills — by a mask-aware
// bilinear sample sum(w c) / sum(w m) (premultiplied source). With the back fill (params.w = 2) occluded pixels
// blend the photo with the back image (stored after the photo in source_color) by the back weight of their
// normal (warp.rs: SourceColours::sample, back_weight, source_axis), and with the side images (stored after
// them, frame.source_images.x = 1) every pixel blends them in by its side weight (warp.rs: side_weight). Writes
// level 0 of the hole-filling pyramid:
// (colour, 1) where known, 0 where a hole.
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;

layout(std430, set = 0, binding = 1) readonly buffer Geometry { vec4 geometry[]; };
layout(std430, set = 0, binding = 2) readonly buffer Color { vec4 color[]; };
layout(std430, set = 0, binding = 3) readonly buffer Flow { vec4 flow[]; };
layout(std430, set = 0, binding = 7) readonly buffer SourceColor { vec4 source_color[]; };
layout(std430, set = 0, binding = 15) buffer Pyramid { vec4 pyramid[]; };

// BACK_FACING_RAMP and SIDE_RAMP of warp.rs.
const float BACK_FACING_RAMP = 0.3;
const float SIDE_RAMP = 0.5;

// Mask-aware bilinear sample of the premultiplied image starting at `base` in source_color (warp.rs:
// sample_masked); w = 0 where the mask weight is below 0.05.
vec4 sample_masked(vec2 p, int sw, int sh, int base) {
    float fx = p.x - 0.5;
    float fy = p.y - 0.5;
    float x0 = floor(fx);
    float y0 = floor(fy);
    float tx = fx - x0;
    float ty = fy - y0;
    int c0 = int(x0);
    int r0 = int(y0);
    vec3 acc = vec3(0.0);
    float wm = 0.0;
    for (int k = 0; k < 4; k++) {
        int dc = k & 1;
        int dr = k >> 1;
        float wt = (dc == 0 ? 1.0 - tx : tx) * (dr == 0 ? 1.0 - ty : ty);
        int c = c0 + dc;
        int r = r0 + dr;
        if (c < 0 || r < 0 || c >= sw || r >= sh || wt <= 0.0) {
            continue;
        }
        vec4 s = source_color[base + r * sw + c];
        float m = clamp(s.w, 0.0, 1.0);
        if (m > 0.0) {
            acc += s.rgb * wt;
            wm += m * wt;
        }
    }
    return wm >= 0.05 ? vec4(acc / wm, 1.0) : vec4(0.0);
}

// The photo (at `base`) blended with the back image (one image further) by `back` (warp.rs: sample_sharp).
vec4 sample_blend(vec2 p, int sw, int sh, int base, float back) {
    if (back <= 0.0) {
        return sample_masked(p, sw, sh, base);
    }
    vec4 behind = sample_masked(p, sw, sh, base + sw * sh);
    if (back >= 1.0) {
        return behind;
    }
    vec4 front = sample_masked(p, sw, sh, base);
    return front.w > 0.0 ? front * (1.0 - back) + behind * back : front;
}

void main() {
    uint width = uint(frame.target.info.y);
    uint height = uint(frame.target.info.z);
    uvec2 id = gl_GlobalInvocationID.xy;
    if (id.x >= width || id.y >= height) {
        return;
    }
    uint index = id.y * width + id.x;
    vec4 result = vec4(0.0);
    vec4 f = flow[index];
    bool visible = f.w > 1.5;
    bool take = visible || (f.w > 0.5 && abs(frame.params.w - 1.0) > 0.5);
    if (color[index].w > 0.5 && take) {
        int sw = int(frame.sizes.z);
        int sh = int(frame.sizes.w);
        vec3 world = (frame.source.world_from_view * vec4(0.0, 0.0, 1.0, 0.0)).xyz;
        vec3 axis = (frame.target.view_from_world * vec4(world, 0.0)).xyz;
        float len = length(axis);
        axis = len > 0.0 ? axis / len : vec3(0.0);
        float back = 0.0;
        if (!visible && frame.params.w > 1.5) {
            back = smoothstep(0.0, BACK_FACING_RAMP, -dot(geometry[index].xyz, axis));
        }
        result = sample_blend(f.xy, sw, sh, 0, back);
        if (frame.source_images.x != 0u && result.w > 0.0) {
            // The photo's shrink of the surface against this view (warp.rs side_weight); a surface this view
            // sees edge-on keeps the sharp photo.
            float here = abs(geometry[index].z);
            float ratio = here > 0.0 ? abs(dot(geometry[index].xyz, axis)) / here : 1e30;
            float side = 1.0 - smoothstep(0.0, SIDE_RAMP, ratio);
            if (side > 0.0) {
                vec4 blurred = sample_blend(f.xy, sw, sh, 2 * sw * sh, back);
                if (blurred.w > 0.0) {
                    result = side >= 1.0 ? blurred : result * (1.0 - side) + blurred * side;
                }
            }
        }
    }
    pyramid[index] = result;
}
