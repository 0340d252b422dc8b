// Shared declarations for every r2human shader (pulled in by build.rs's `#include`).
// Conventions are the CPU reference's (src/geometry/camera.rs): view space looks down -z, depth = view z
// (larger is nearer), continuous pixel coordinates with centres at +0.5, row 0 at the top.

struct Cam {
    mat4 view_from_world;
    mat4 world_from_view;
    // orthographic: (half_width, half_height, z_min, z_max of the mesh in view space)
    // perspective:  (tan(angle_left), tan(angle_right), tan(angle_up), tan(angle_down))
    vec4 proj;
    // (kind: 0 orthographic / 1 perspective, width, height, near)
    vec4 info;
};

layout(std140, set = 0, binding = 0) uniform Frame {
    Cam target;    // the view being rendered
    Cam source;    // the input photo's camera
    Cam viewer;    // panorama lookup camera (VR)
    Cam previous;  // the previous view (spatial fusion)
    // x: environment yaw (radians), y: weight of the previous output in spatial fusion (Eq. 8),
    // z: visibility lambda (Eq. 9), w: occlusion fill (0 mirrored front, 1 propagate, 2 back)
    vec4 params;
    // rgb: mean colour of the person in the photo (fill when the view sees nothing of the photo)
    vec4 mean_color;
    // x: environment width, y: environment height, z: source width, w: source height
    uvec4 sizes;
    // x: previous view valid (0/1), y: feature channels, z: feature width, w: feature height
    uvec4 flags;
    // x: swizzle to BGRA when encoding (0/1), y: output is an AR layer shown over grey (0/1),
    // z, w: size of the text overlay rectangle at the top left (0: none)
    uvec4 output_format;
    // x: the side images (warp.rs: SideImages) are stored after the photo and the back image (0/1)
    uvec4 source_images;
} frame;

vec2 pixel_to_ndc(Cam c, vec2 px) {
    return vec2(px.x / (0.5 * c.info.y) - 1.0, 1.0 - px.y / (0.5 * c.info.z));
}

vec2 ndc_to_pixel(Cam c, vec2 ndc) {
    return vec2((ndc.x + 1.0) * 0.5 * c.info.y, (1.0 - ndc.y) * 0.5 * c.info.z);
}

// NDC -> tangents (x/-z, y/-z) of a perspective camera.
vec2 ndc_to_tangent(Cam c, vec2 ndc) {
    return vec2(c.proj.x + (ndc.x + 1.0) * 0.5 * (c.proj.y - c.proj.x),
                c.proj.w + (ndc.y + 1.0) * 0.5 * (c.proj.z - c.proj.w));
}

// World point at pixel px with view depth `depth` (Camera::unproject).
vec3 unproject(Cam c, vec2 px, float depth) {
    vec2 ndc = pixel_to_ndc(c, px);
    vec3 p;
    if (c.info.x < 0.5) {
        p = vec3(ndc.x * c.proj.x, ndc.y * c.proj.y, depth);
    } else {
        vec2 t = ndc_to_tangent(c, ndc);
        p = vec3(t.x * -depth, t.y * -depth, depth);
    }
    return (c.world_from_view * vec4(p, 1.0)).xyz;
}

// World point -> (u, v, depth, ok) (Camera::project); ok = 0 when a perspective point is nearer than `near`.
vec4 project(Cam c, vec3 world) {
    vec3 p = (c.view_from_world * vec4(world, 1.0)).xyz;
    vec2 ndc;
    if (c.info.x < 0.5) {
        ndc = vec2(p.x / c.proj.x, p.y / c.proj.y);
    } else {
        if (-p.z < c.info.w) {
            return vec4(0.0, 0.0, p.z, 0.0);
        }
        vec2 t = p.xy / -p.z;
        ndc = vec2((2.0 * t.x - (c.proj.y + c.proj.x)) / (c.proj.y - c.proj.x),
                   (2.0 * t.y - (c.proj.z + c.proj.w)) / (c.proj.z - c.proj.w));
    }
    return vec4(ndc_to_pixel(c, ndc), p.z, 1.0);
}

// World-space unit direction of the viewing ray through pixel px (Camera::ray).
vec3 ray_direction(Cam c, vec2 px) {
    vec3 d;
    if (c.info.x < 0.5) {
        d = vec3(0.0, 0.0, -1.0);
    } else {
        vec2 t = ndc_to_tangent(c, pixel_to_ndc(c, px));
        d = vec3(t, -1.0);
    }
    return normalize((c.world_from_view * vec4(d, 0.0)).xyz);
}

// Level offsets and sizes for the push-pull pyramid passes.
layout(push_constant) uniform Level {
    uint src_offset;
    uint src_width;
    uint src_height;
    uint dst_offset;
    uint dst_width;
    uint dst_height;
    uint top_offset;
    uint pad;
} level;
