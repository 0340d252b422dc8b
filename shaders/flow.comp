#version 450
// Flow and Z-map of paper Eq. 4 and visibility of Eq. 9 (src/geometry/zmap.rs): for each covered target pixel,
// the surface point's continuous pixel coordinate and view depth in the source camera, and whether the source
// camera sees that point (nearest lookup of its depth at the flow, |z - D| < lambda * s).
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;

layout(std430, set = 0, binding = 1) readonly buffer Geometry { vec4 geometry[]; };
layout(std430, set = 0, binding = 2) readonly buffer Color { vec4 color[]; };
// (flow u, flow v, z_src, state): state 0 = no flow, 1 = flow but hidden in the source, 2 = visible.
layout(std430, set = 0, binding = 3) buffer Flow { vec4 flow[]; };
layout(std430, set = 0, binding = 8) readonly buffer SourceGeometry { vec4 source_geometry[]; };

void main() {
    uint width = uint(frame.target.info.y);
    uint height = uint(frame.target.info.z);
    uvec2 id = gl_GlobalInvocationID.xy;
    if (id.x >= width || id.y >= height) {
        return;
    }
    uint index = id.y * width + id.x;
    vec4 outside = vec4(-1.0, -1.0, 0.0, 0.0);
    if (color[index].w <= 0.5) {
        flow[index] = outside;
        return;
    }
    vec3 world = unproject(frame.target, vec2(id) + 0.5, geometry[index].w);
    vec4 q = project(frame.source, world);
    // A point the source cannot project (behind a perspective near plane) or a non-finite result has no flow.
    if (q.w < 0.5 || !(abs(q.x) < 1e30 && abs(q.y) < 1e30 && abs(q.z) < 1e30)) {
        flow[index] = outside;
        return;
    }
    float state = 1.0;
    int sw = int(frame.sizes.z);
    int sh = int(frame.sizes.w);
    float x = floor(q.x);
    float y = floor(q.y);
    if (x >= 0.0 && y >= 0.0 && x < float(sw) && y < float(sh)) {
        vec4 s = source_geometry[int(y) * sw + int(x)];
        // Source geometry is (normal, depth) with depth -1e30 where the source sees nothing.
        if (s.w > -1e29) {
            float d = s.w;
            float scale = frame.source.info.x < 0.5 ? 1.0 + min(q.z, d) : min(-q.z, -d);
            if (scale > 0.0 && abs(q.z - d) < frame.params.z * scale) {
                state = 2.0;
            }
        }
    }
    flow[index] = vec4(q.xy, q.z, state);
}
