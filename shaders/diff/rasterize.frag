#version 450 core
// The differentiable rasterize's raster pass (glraster/diff/rasterize.py): coverage, the
// depth test and the triangle of each pixel, from the driver. Writes, per covered pixel,
// the drawn triangle's index + 1 (over the whole draw: tri_base + gl_PrimitiveID; the
// clear value 0 marks empty pixels); the resolve pass (shaders/diff/rasterize.comp) then
// computes rast and rast_db at each pixel centre from that triangle's setup record. Each
// covered pixel is evaluated once there, where shading here would evaluate every fragment
// that passes the depth test so far (later ones overwrite it) in llvmpipe's 4x4 blocks.
//
// Host defines: PEEL (discard fragments at or in front of the previous layer's z/w,
// prev_depth: z/w is evaluated here from the record at binding 2, the same operations as
// the resolve pass's).

layout(location = 0) out int out_drawn;
uniform int tri_base;  // index of the storage batch's first triangle (set by the pipeline)

#ifdef PEEL
#define RECORDS_IN_BUFFER
#include "rasterize_record.glsl"
uniform sampler2D prev_depth;  // (H, W) previous layer's z/w; +inf where it was empty
#endif

void main() {
#ifdef PEEL
    float r[RECORD_STRIDE];
    load_record(gl_PrimitiveID, r);
    float z = depth_of(r, scaled_coordinates(r, gl_FragCoord.xy));
    if (z <= texelFetch(prev_depth, ivec2(gl_FragCoord.xy), 0).r) {
        discard;
    }
#endif
    out_drawn = tri_base + gl_PrimitiveID + 1;
}
