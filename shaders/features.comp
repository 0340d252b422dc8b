#version 450
// Feature warp for the neural decoder (src/pipeline/warp.rs, warp_features): bilinear sample of a
// channels x fh x fw map at the flow scaled by fw / source resolution (align_corners = false), zero outside the
// map and outside the flow mask; output channels x H x W.
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;

layout(std430, set = 0, binding = 3) readonly buffer Flow { vec4 flow[]; };
layout(std430, set = 0, binding = 11) readonly buffer Features { float features[]; };
layout(std430, set = 0, binding = 12) buffer Warped { float warped[]; };

void main() {
    uint width = uint(frame.target.info.y);
    uint height = uint(frame.target.info.z);
    uvec2 id = gl_GlobalInvocationID.xy;
    if (id.x >= width || id.y >= height) {
        return;
    }
    uint index = id.y * width + id.x;
    uint plane = width * height;
    uint channels = frame.flags.y;
    int fw = int(frame.flags.z);
    int fh = int(frame.flags.w);
    uint fplane = uint(fw * fh);
    vec4 f = flow[index];
    float sx = float(fw) / float(frame.sizes.z);
    float sy = float(fh) / float(frame.sizes.z);
    float x = f.x * sx - 0.5;
    float y = f.y * sy - 0.5;
    bool inside = f.w > 0.5 && x > -1.0 && y > -1.0 && x < float(fw) && y < float(fh);
    if (!inside) {
        for (uint ch = 0u; ch < channels; ch++) {
            warped[ch * plane + index] = 0.0;
        }
        return;
    }
    float x0 = floor(x);
    float y0 = floor(y);
    float tx = x - x0;
    float ty = y - y0;
    int xi = int(x0);
    int yi = int(y0);
    int taps[4];
    float weights[4];
    for (int k = 0; k < 4; k++) {
        int c = xi + (k & 1);
        int r = yi + (k >> 1);
        float wt = ((k & 1) == 0 ? 1.0 - tx : tx) * ((k >> 1) == 0 ? 1.0 - ty : ty);
        bool ok = c >= 0 && r >= 0 && c < fw && r < fh;
        taps[k] = ok ? r * fw + c : 0;
        weights[k] = ok ? wt : 0.0;
    }
    for (uint ch = 0u; ch < channels; ch++) {
        uint base = ch * fplane;
        float v = 0.0;
        for (int k = 0; k < 4; k++) {
            v += features[base + uint(taps[k])] * weights[k];
        }
        warped[ch * plane + index] = v;
    }
}
