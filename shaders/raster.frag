#version 450
// Writes (view-space unit normal, view depth) and (colour, coverage) for the nearest surface.

layout(location = 0) in vec3 v_normal;
layout(location = 1) in float v_depth;
layout(location = 2) in vec3 v_color;

layout(location = 0) out vec4 o_geometry;
layout(location = 1) out vec4 o_color;

void main() {
    float len = length(v_normal);
    vec3 n = len > 1e-12 ? v_normal / len : vec3(0.0, 0.0, 1.0);
    o_geometry = vec4(n, v_depth);
    o_color = vec4(v_color, 1.0);
}
