// The gathered inputs of interpolate's passes, read through buffer textures over their
// buffers (GL 4.6 section 8.9, texelFetch): on llvmpipe a texel fetch at per-lane addresses
// is several times faster than a storage-buffer load, and returns the same floats. Units
// from TEXEL_UNIT: + 0 the attributes (ATTR_VEC floats a texel, ATTR_VEC dividing N_ATTR),
// + 1 the triangles (RGB32I, one a texel), + 2 rast, + 3 rast_db (RGBA32F, one pixel a
// texel); the backward adds + 4 dL/d out (as the attributes), + 5 dL/d out_da (RG32F, one
// (d/dx, d/dy) pair a texel).
#define ROW (N_ATTR > 0 ? N_ATTR : 1)
#define ROW_FETCHES (N_ATTR / ATTR_VEC)

layout(binding = TEXEL_UNIT) uniform samplerBuffer attr;
layout(binding = TEXEL_UNIT + 1) uniform isamplerBuffer tri;
layout(binding = TEXEL_UNIT + 2) uniform samplerBuffer rast;
#if N_DIFF > 0
layout(binding = TEXEL_UNIT + 3) uniform samplerBuffer rast_db;
#endif

// the N_ATTR floats of row `row` (a vertex of attr, a pixel of dL/d out) of `view` into a
void load_row(samplerBuffer view, uint row, out float a[ROW]) {
    int first = int(row) * ROW_FETCHES;
    for (int q = 0; q < ROW_FETCHES; ++q) {
        vec4 f = texelFetch(view, first + q);
        for (int c = 0; c < ATTR_VEC; ++c) a[q * ATTR_VEC + c] = f[c];
    }
}
