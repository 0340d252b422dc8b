#version 450
// End of the geometric warp: premultiplied RGBA with alpha = target coverage, colour clamped to [0, 1]; when
// nothing of the photo was seen at all (empty pyramid top), the photo's mean person colour.
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;

layout(std430, set = 0, binding = 2) readonly buffer Color { vec4 color[]; };
layout(std430, set = 0, binding = 14) buffer Current { vec4 current[]; };
layout(std430, set = 0, binding = 15) readonly buffer Pyramid { vec4 pyramid[]; };

void main() {
    uint width = uint(frame.target.info.y);
    uint height = uint(frame.target.info.z);
    uvec2 id = gl_GlobalInvocationID.xy;
    if (id.x >= width || id.y >= height) {
        return;
    }
    uint index = id.y * width + id.x;
    vec4 result = vec4(0.0);
    if (color[index].w > 0.5) {
        vec3 c = pyramid[level.top_offset].w > 0.0 ? pyramid[index].rgb : frame.mean_color.rgb;
        result = vec4(clamp(c, vec3(0.0), vec3(1.0)), 1.0);
    }
    current[index] = result;
}
