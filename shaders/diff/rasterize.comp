#version 450 core
// The differentiable rasterize's resolve pass (glraster/diff/rasterize.py, docs/
// differentiable.md): one invocation per pixel of a band of rows of up to GROUP_ITEMS
// images (item k = gl_GlobalInvocationID.z: one dispatch for a group of small images),
// reading the raster pass's drawn triangle index + 1 (shaders/diff/rasterize.frag, 0:
// empty; item k's at image unit k) and writing, row 0 at the bottom, pixel (x, y) of item
// k's band at (k rows + y - first_row) W + x:
//   rast    = (u, v, z/w, id): u = b0, v = b1, the perspective-correct barycentrics of the
//             triangle's vertices 0 and 1 (SPACE_SCREEN: the window-space ones), z/w the
//             NDC depth z_c / w_c of the surface point, id = triangle index + 1 encoded as
//             a float (include/triangle_id.glsl); 0 on empty pixels.
//   rast_db = (du/dx, du/dy, dv/dx, dv/dy) at the pixel centre, in window pixels.
//
// With homogeneous window coordinates X_j = (x_j + w_j) W/2, Y_j = (y_j + w_j) H/2 and
// M = [[X_j], [Y_j], [w_j]], row i of adj(M) is the edge function e_i = A_i x + B_i y + C_i
// and s_i = e_i / det(M) (Olano & Greer 1997). With S = sum_j s_j (= 1 / w of the surface
// point), b_i = s_i / S, and
//   d b_i / dx = (g_i - b_i sum_j g_j) / S,   g_i = d s_i / dx = A_i / det  (y: B_i)
//   window-space barycentrics s_i w_i have d (s_i w_i) / dx = g_i w_i
//   z / w = sum_i s_i z_i                     (M s = (x, y, 1): sum_i s_i w_i = 1)
// All of it is evaluated at the pixel centre (x + 0.5, y + 0.5), gl_FragCoord's value
// there, from the triangle's setup record (rasterize_record.glsl): the derivatives are
// the exact closed form at the centre, not a 2x2-quad difference.
//
// Item k's bound records (in the texture ``records``, from record record_base[k]) are
// those of its drawn triangles record_first .. record_first + record_count[k] - 1 (one
// texture's worth); a pixel of another triangle is left to the dispatch of its own
// records, an empty one is written by the dispatch with write_empty.
//
// Host defines: RECORDS_PER_ROW (the record texture's layout); OUT_RAST_DB; SPACE_SCREEN;
// REMAP (ids[ids_first[k] + t] at binding 5 holds the caller's triangle index of item k's
// bound record t).

layout(local_size_x = 8, local_size_y = 8) in;

#include "rasterize_record.glsl"
#include "include/triangle_id.glsl"

#define GROUP_ITEMS 4  // glraster.gpu.context.FRAMEBUFFER_SLOTS
layout(r32i, binding = 0) uniform readonly iimage2D drawn_0;  // the raster passes' targets
layout(r32i, binding = 1) uniform readonly iimage2D drawn_1;
layout(r32i, binding = 2) uniform readonly iimage2D drawn_2;
layout(r32i, binding = 3) uniform readonly iimage2D drawn_3;
layout(std430, binding = 3) writeonly buffer Rast { vec4 out_rast[]; };
#ifdef OUT_RAST_DB
layout(std430, binding = 4) writeonly buffer RastDb { vec4 out_rast_db[]; };
#endif
#ifdef REMAP
layout(std430, binding = 5) readonly buffer Ids { int ids[]; };
uniform int ids_first[GROUP_ITEMS];
#endif

uniform ivec2 size;        // (W, rows of the band)
uniform int first_row;     // the band's first row
uniform int record_first;  // drawn index of the bound records' first triangle
uniform int record_base[GROUP_ITEMS];  // texture index of item k's record 0
uniform int record_count[GROUP_ITEMS];
uniform int write_empty;   // 1: also write the empty pixels
uniform int id_base[GROUP_ITEMS];  // index in the caller's tri of the draw's first triangle

int drawn_at(int item, ivec2 pixel) {
    if (item == 0) {
        return imageLoad(drawn_0, pixel).r;
    } else if (item == 1) {
        return imageLoad(drawn_1, pixel).r;
    } else if (item == 2) {
        return imageLoad(drawn_2, pixel).r;
    }
    return imageLoad(drawn_3, pixel).r;
}

void main() {
    ivec2 local = ivec2(gl_GlobalInvocationID.xy);
    int item = int(gl_GlobalInvocationID.z);
    if (local.x >= size.x || local.y >= size.y) {
        return;
    }
    ivec2 pixel = ivec2(local.x, first_row + local.y);
    int slot = (item * size.y + local.y) * size.x + local.x;
    int drawn = drawn_at(item, pixel);  // drawn index + 1, 0: empty
    if (drawn == 0) {
        if (write_empty != 0) {
            out_rast[slot] = vec4(0.0);
#ifdef OUT_RAST_DB
            out_rast_db[slot] = vec4(0.0);
#endif
        }
        return;
    }
    int t = drawn - 1 - record_first;  // in the bound records
    if (t < 0 || t >= record_count[item]) {
        return;
    }
    float r[RECORD_STRIDE];
    load_record(record_base[item] + t, r);
    vec3 s = scaled_coordinates(r, vec2(pixel) + 0.5);
    float z = depth_of(r, s);
    vec3 gx = vec3(r[2], r[3], r[4]);
    vec3 gy = vec3(r[8], r[9], r[10]);
#ifdef SPACE_SCREEN
    vec3 wk = vec3(r[20], r[21], r[22]);
    vec3 b = s * wk;
    vec3 bx = gx * wk;
    vec3 by = gy * wk;
#else
    float total = s.x + s.y + s.z;           // k S = k / w of the surface point
    float inv = total != 0.0 ? 1.0 / total : 0.0;
    vec3 b = vec3(s.x / total, s.y / total, s.z / total);
    if (total == 0.0) {
        b = vec3(0.0);
    }
    vec3 bx = (gx - b * (gx.x + gx.y + gx.z)) * inv;
    vec3 by = (gy - b * (gy.x + gy.y + gy.z)) * inv;
#endif
#ifdef REMAP
    int id = ids[ids_first[item] + t] + 1;
#else
    int id = id_base[item] + record_first + t + 1;
#endif
    out_rast[slot] = vec4(b.x, b.y, z, encode_id(id));
#ifdef OUT_RAST_DB
    out_rast_db[slot] = vec4(bx.x, by.x, bx.y, by.y);
#endif
}
