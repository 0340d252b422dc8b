#version 450
// Target-view rasterisation of the mesh: view-space depth and normals (and per-vertex colour) per pixel.
#include "common.glsl"

layout(location = 0) in vec3 position;
layout(location = 1) in vec3 normal;
layout(location = 2) in vec3 color;

layout(location = 0) out vec3 v_normal;
layout(location = 1) out float v_depth;
layout(location = 2) out vec3 v_color;

void main() {
    Cam c = frame.target;
    vec3 p = (c.view_from_world * vec4(position, 1.0)).xyz;
    v_normal = (c.view_from_world * vec4(normal, 0.0)).xyz;
    v_depth = p.z;
    v_color = color;
    if (c.info.x < 0.5) {
        // Orthographic: Vulkan y points down; depth maps [z_min, z_max] to [0, 1] (greater = nearer).
        float depth = (p.z - c.proj.z) / max(c.proj.w - c.proj.z, 1e-6);
        gl_Position = vec4(p.x / c.proj.x, -p.y / c.proj.y, depth, 1.0);
    } else {
        // Perspective with reversed depth near / distance (1 at the near plane, -> 0 far; greater = nearer).
        float tl = c.proj.x;
        float tr = c.proj.y;
        float tu = c.proj.z;
        float td = c.proj.w;
        float cx = (2.0 * p.x + (tr + tl) * p.z) / (tr - tl);
        float cy = (2.0 * p.y + (tu + td) * p.z) / (tu - td);
        gl_Position = vec4(cx, -cy, c.info.w, -p.z);
    }
}
