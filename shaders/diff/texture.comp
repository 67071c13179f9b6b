#version 450
// Filtered texture lookups (forward) and their gradients (with BACKWARD), one invocation per
// pixel; the level and the filter are computed here from texel fetches (no GL sampler):
//   level = 0.5 log2(lenMajorSqr) + bias, clamped to [0, n_levels - 1]
//   (docs/differentiable.md, "Texture")
//   bilinear at texel centres: x = s W_l - 0.5, taps floor(x), floor(x) + 1 (y alike)
// Defines: FILTER 0 nearest | 1 linear | 2 linear-mipmap-nearest | 3 linear-mipmap-linear;
// BOUNDARY 0 wrap | 1 clamp | 2 zero | 3 cube; HAS_DA, HAS_BIAS; CHANNELS (floats per
// texel: a constant, so the channel loops unroll); with BACKWARD either TEX_GRAD and one of
// ACCUM_ATOMIC_FLOAT | ACCUM_CAS | ACCUM_FIXED_POINT (deterministic: see spread), or no
// TEX_GRAD (no texel gradient wanted: nothing is spread); with BACKWARD, RUN consecutive
// pixels per invocation (their terms for a texel they share summed before one atomic add);
// COORD_GRAD: the gradients to uv, uv_da and the bias are wanted (else neither computed nor
// written).
// Layouts (flattened pixels of this dispatch, i = 0 .. n_pixels - 1):
//   texels  every level (base first), level l from texel level_info[l].x on, texel
//           ((image * faces + face) * H + j) * W + i, `channels` floats per texel, read
//           through a buffer texture over the levels' storage buffer (TEXEL_VEC floats per
//           fetch, a define: 4, 2 or 1): llvmpipe's texel fetches are several times faster
//           than its storage-buffer loads at scattered addresses, and return the same floats
//   uv      NCOORD floats per pixel; uv_da 2 NCOORD; bias 1; out / grad_out `channels`
#if defined(BACKWARD) && defined(ACCUM_ATOMIC_FLOAT)
#extension GL_NV_shader_atomic_float : require
#endif

layout(local_size_x = 64) in;

#if BOUNDARY == 3
#define NCOORD 3
#define FACES 6
#else
#define NCOORD 2
#define FACES 1
#endif
#define MIP (FILTER >= 2)

// texture unit TEXEL_UNIT (a define); GL 4.6 section 8.9 (buffer textures), texelFetch
layout(binding = TEXEL_UNIT) uniform samplerBuffer texels;
// per level (first texel, H, W, 0), an RGBA32I buffer texture
layout(binding = TEXEL_UNIT + 5) uniform isamplerBuffer level_info_view;
#define LEVEL_INFO(l) texelFetch(level_info_view, (l))
// the per-pixel inputs too, through buffer textures on the next units (same reason):
// uv NCOORD floats a fetch, uv_da and the bias one, dL/d out TEXEL_VEC
layout(binding = TEXEL_UNIT + 1) uniform samplerBuffer uv;
#ifdef HAS_DA
layout(binding = TEXEL_UNIT + 2) uniform samplerBuffer uv_da_view;
#define UV_DA(k) texelFetch(uv_da_view, int(k)).x
#endif
#ifdef HAS_BIAS
layout(binding = TEXEL_UNIT + 3) uniform samplerBuffer bias;
#endif
#ifndef BACKWARD
// out as whole texels where they are 4 floats (one store a pixel, not one a channel)
#if CHANNELS == 4
layout(std430, binding = 5) writeonly buffer Out { vec4 out_tex[]; };
#else
layout(std430, binding = 5) writeonly buffer Out { float out_tex[]; };
#endif
#else
layout(binding = TEXEL_UNIT + 4) uniform samplerBuffer grad_out;
// 2-D: one store a pixel (vec2 uv, vec4 uv_da gradients), not one a float
#if NCOORD == 2
layout(std430, binding = 6) writeonly buffer GradUv { vec2 grad_uv[]; };
#else
layout(std430, binding = 6) writeonly buffer GradUv { float grad_uv[]; };
#endif
#ifdef HAS_DA
#if NCOORD == 2
layout(std430, binding = 7) writeonly buffer GradDa { vec4 grad_da[]; };
#else
layout(std430, binding = 7) writeonly buffer GradDa { float grad_da[]; };
#endif
#endif
#ifdef HAS_BIAS
layout(std430, binding = 8) writeonly buffer GradBias { float grad_bias[]; };
#endif
#if !defined(TEX_GRAD)
#elif defined(ACCUM_ATOMIC_FLOAT)
layout(std430, binding = 9) buffer GradTex { float grad_tex[]; };
#elif defined(ACCUM_CAS)
layout(std430, binding = 9) buffer GradTex { uint grad_tex[]; };
#else
// 64-bit two's complement integers, (low word, high word) per texel float
layout(std430, binding = 9) buffer GradTex { uint grad_tex[]; };
#endif
#if defined(TEX_GRAD) && MIP
// the highest level any pixel read (the host pulls back only the levels up to it)
layout(std430, binding = 10) buffer TopLevel { int top_level_read; };
#endif
#endif

uniform uint n_pixels;
uniform uint first_pixel;
uniform uint pixels_per_image;
uniform int tex_batch;      // 1 (broadcast) or B
uniform int n_levels;
const int channels = CHANNELS;
#ifdef ACCUM_FIXED_POINT
uniform float fixed_scale_a;  // 2^k: a contribution v is added as round(v 2^k), split into
uniform float fixed_scale_b;  // two power-of-two factors that each stay in float range
#endif

// cube faces +x, -x, +y, -y, +z, -z (GL table 8.19): s_c = sigma_s d[axis_s],
// t_c = sigma_t d[axis_t], m = sigma_m d[axis_m] > 0, with per face
//   (axis_s, axis_t, axis_m)    (2, 1, 0) (2, 1, 0) (0, 2, 1) (0, 2, 1) (0, 1, 2) (0, 1, 2)
//   (sigma_s, sigma_t, sigma_m) (-1, -1, 1) (1, -1, -1) (1, 1, 1) (1, -1, -1) (1, -1, 1)
//                               (-1, -1, -1)
// read from bit masks (2 bits a face for the axes, 1 for a negative sign): shifts
// vectorise, where indexing a constant table by a per-pixel face is a gather
ivec3 face_axes(int f) { return ivec3((10 >> (2 * f)) & 3, (1445 >> (2 * f)) & 3, f >> 1); }
ivec3 face_signs(int f) {
    return ivec3(1 - 2 * ((33 >> f) & 1), 1 - 2 * ((59 >> f) & 1), 1 - 2 * (f & 1));
}

int major_face(vec3 d) {
    vec3 a = abs(d);
    int axis = (a.x >= a.y && a.x >= a.z) ? 0 : (a.y >= a.z ? 1 : 2);
    return 2 * axis + (d[axis] >= 0.0 ? 0 : 1);
}

int major_face_i(ivec3 d) {
    ivec3 a = abs(d);
    int axis = (a.x >= a.y && a.x >= a.z) ? 0 : (a.y >= a.z ? 1 : 2);
    return 2 * axis + (d[axis] >= 0 ? 0 : 1);
}

// a / b for 0 <= a, 0 < b (integer division, truncating): the quotient in float
// (vectorises, unlike integer division; llvmpipe runs a masked branch's division for
// every lane), then one step of correction each way: exact for a / b < 2^22 (float's
// two roundings then err by less than 1; here a / b <= n) and (a / b + 1) b in int range
int quotient(int a, int b) {
    int q = int(float(a) / float(b));
    if (q * b > a) q -= 1;
    if ((q + 1) * b <= a) q += 1;
    return q;
}

// the texel that continues `face` beyond its edge (one of i, j is -1 or n): the direction
// of the texel centre, in half texels, projected onto the face of its major axis
ivec3 cube_neighbour(int face, int i, int j, int n) {
    ivec3 ax = face_axes(face), sg = face_signs(face);
    ivec3 d = ivec3(0);
    d[ax.x] = sg.x * (2 * i + 1 - n);
    d[ax.y] = sg.y * (2 * j + 1 - n);
    d[ax.z] = sg.z * n;
    int f2 = major_face_i(d);
    ivec3 ax2 = face_axes(f2), sg2 = face_signs(f2);
    int m = sg2.z * d[ax2.z];
    int s2 = sg2.x * d[ax2.x], t2 = sg2.y * d[ax2.y];
    return ivec3(f2, quotient((s2 + m) * n, 2 * m), quotient((t2 + m) * n, 2 * m));
}

// i mod n in [0, n): the quotient in float (vectorises, unlike integer division), then at
// most one step of correction, exact for |i| < 2^24
int wrap_index(int i, int n) {
    int r = i - n * int(floor(float(i) / float(n)));
    if (r < 0) r += n;
    if (r >= n) r -= n;
    return r;
}

// four taps of one level: global texel index (-1: none), weight and its s, t derivatives
struct Taps { ivec4 index; vec4 w; vec4 ds; vec4 dt; };

Taps bilinear(int level, float s, float t, int image, int face) {
    ivec4 info = LEVEL_INFO(level);
    int H = info.y, W = info.z;
    float x = s * float(W) - 0.5, y = t * float(H) - 0.5;
    float fx0 = floor(x), fy0 = floor(y);
    int i0 = int(fx0), j0 = int(fy0);
    float fx = x - fx0, fy = y - fy0;
    Taps r;
    r.w = vec4((1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy);
    r.ds = vec4(-(1.0 - fy), 1.0 - fy, -fy, fy) * float(W);
    r.dt = vec4(-(1.0 - fx), -fx, 1.0 - fx, fx) * float(H);
    ivec4 ii = ivec4(i0, i0 + 1, i0, i0 + 1), jj = ivec4(j0, j0, j0 + 1, j0 + 1);
#if BOUNDARY == 3
    int corner = -1;
    for (int k = 0; k < 4; ++k) {
        bool oi = ii[k] < 0 || ii[k] >= W, oj = jj[k] < 0 || jj[k] >= H;
        int f = face, a = ii[k], b = jj[k];
        if (oi && oj) { corner = k; r.index[k] = -1; continue; }
        if (oi || oj) { ivec3 nb = cube_neighbour(face, a, b, W); f = nb.x; a = nb.y; b = nb.z; }
        r.index[k] = info.x + ((image * 6 + f) * H + b) * W + a;
    }
    if (corner >= 0) {  // no texel there: the mean of the three around the corner
        float w3 = r.w[corner] / 3.0, s3 = r.ds[corner] / 3.0, t3 = r.dt[corner] / 3.0;
        for (int k = 0; k < 4; ++k) {
            if (k == corner) continue;
            r.w[k] += w3; r.ds[k] += s3; r.dt[k] += t3;
        }
        r.w[corner] = 0.0; r.ds[corner] = 0.0; r.dt[corner] = 0.0;
    }
#else
    for (int k = 0; k < 4; ++k) {
        int a = ii[k], b = jj[k];
#if BOUNDARY == 0
        a = wrap_index(a, W); b = wrap_index(b, H);
#elif BOUNDARY == 1
        a = clamp(a, 0, W - 1); b = clamp(b, 0, H - 1);
#else
        if (a < 0 || a >= W || b < 0 || b >= H) {
            r.index[k] = -1; r.w[k] = 0.0; r.ds[k] = 0.0; r.dt[k] = 0.0; continue;
        }
#endif
        r.index[k] = info.x + (image * H + b) * W + a;
    }
#endif
    return r;
}

int nearest_texel(float s, float t, int image, int face) {
    ivec4 info = LEVEL_INFO(0);
    int H = info.y, W = info.z;
    int i = int(floor(s * float(W))), j = int(floor(t * float(H)));
#if BOUNDARY == 0
    i = wrap_index(i, W); j = wrap_index(j, H);
#elif BOUNDARY == 2
    if (i < 0 || i >= W || j < 0 || j >= H) return -1;
#else
    i = clamp(i, 0, W - 1); j = clamp(j, 0, H - 1);
#endif
    return ((image * FACES + face) * H + j) * W + i;
}

// everything one pixel needs: up to two levels of taps, the level weights, the level's
// derivatives
struct Pixel {
    Taps t0, t1;
    float frac;           // weight of t1 (linear-mipmap-linear)
    bool live_level;      // 0 < level < top: the level carries a gradient
    int last_level;       // the highest level read (mipmapped filters)
    int nearest;          // FILTER 0
    float dlevel_da[6];
    vec3 dlevel_duv;
    vec3 ds_duv, dt_duv;  // cube: face coordinates by the direction
    bool ok;
};

Pixel setup(uint i, int image) {
    Pixel p;
    p.ok = true;
    p.frac = 0.0;
    p.live_level = false;
    p.last_level = 0;
    p.nearest = -1;
    p.dlevel_duv = vec3(0.0);
    p.ds_duv = vec3(0.0);
    p.dt_duv = vec3(0.0);
    for (int k = 0; k < 6; ++k) p.dlevel_da[k] = 0.0;
    int face = 0;
    float s, t;
#if BOUNDARY == 3
    vec3 d = texelFetch(uv, int(i)).xyz;
    face = major_face(d);
    ivec3 ax = face_axes(face), sg = face_signs(face);
    float m = float(sg.z) * d[ax.z];
    p.ok = m > 0.0;
    if (!p.ok) m = 1.0;
    float sc = float(sg.x) * d[ax.x], tc = float(sg.y) * d[ax.y];
    s = p.ok ? (sc / m + 1.0) * 0.5 : 0.5;
    t = p.ok ? (tc / m + 1.0) * 0.5 : 0.5;
    if (p.ok) {
        p.ds_duv[ax.x] += float(sg.x) / (2.0 * m);
        p.ds_duv[ax.z] -= sc * float(sg.z) / (2.0 * m * m);
        p.dt_duv[ax.y] += float(sg.y) / (2.0 * m);
        p.dt_duv[ax.z] -= tc * float(sg.z) / (2.0 * m * m);
    }
#else
    vec2 st = texelFetch(uv, int(i)).xy;
    s = st.x;
    t = st.y;
#endif
#if FILTER == 0
    p.nearest = nearest_texel(s, t, image, face);
    if (p.nearest >= 0) p.nearest += LEVEL_INFO(0).x;
#elif FILTER == 1
    p.t0 = bilinear(0, s, t, image, face);
#else
    float level = 0.0;
    int top = n_levels - 1;
#ifdef HAS_DA
    float h0 = float(LEVEL_INFO(0).y), w0 = float(LEVEL_INFO(0).z);
    float a, b, c, dd;
#if BOUNDARY == 3
    float psx = float(sg.x) * UV_DA(6u * i + uint(2 * ax.x));
    float psy = float(sg.x) * UV_DA(6u * i + uint(2 * ax.x + 1));
    float ptx = float(sg.y) * UV_DA(6u * i + uint(2 * ax.y));
    float pty = float(sg.y) * UV_DA(6u * i + uint(2 * ax.y + 1));
    float mx = float(sg.z) * UV_DA(6u * i + uint(2 * ax.z));
    float my = float(sg.z) * UV_DA(6u * i + uint(2 * ax.z + 1));
    float kk = p.ok ? w0 * 0.5 : 0.0;
    float im = 1.0 / m, im2 = im * im;
    a = kk * (psx * im - sc * mx * im2);
    b = kk * (psy * im - sc * my * im2);
    c = kk * (ptx * im - tc * mx * im2);
    dd = kk * (pty * im - tc * my * im2);
#else
    a = UV_DA(4u * i) * w0;
    b = UV_DA(4u * i + 1u) * w0;
    c = UV_DA(4u * i + 2u) * h0;
    dd = UV_DA(4u * i + 3u) * h0;
#endif
    float A = a * a + c * c, B = b * b + dd * dd, C = a * b + c * dd;
    float half_ab = (A - B) * 0.5;
    float l2a = sqrt(half_ab * half_ab + C * C);
    float major = (A + B) * 0.5 + l2a;
    level = major > 0.0 ? 0.5 * log2(major) : -1.0e30;
#ifdef BACKWARD
    float inv = l2a > 0.0 ? 1.0 / l2a : 0.0;
    float g = major > 0.0 ? 1.0 / (2.0 * 0.6931471805599453 * major) : 0.0;
    float gA = g * (0.5 + half_ab * inv * 0.5), gB = g * (0.5 - half_ab * inv * 0.5);
    float gC = g * C * inv;
    float ga = 2.0 * a * gA + b * gC, gb = 2.0 * b * gB + a * gC;
    float gc = 2.0 * c * gA + dd * gC, gd = 2.0 * dd * gB + c * gC;
#if BOUNDARY == 3
    float g_psx = ga * kk * im, g_psy = gb * kk * im, g_ptx = gc * kk * im, g_pty = gd * kk * im;
    float g_mx = -kk * (ga * sc + gc * tc) * im2, g_my = -kk * (gb * sc + gd * tc) * im2;
    float g_ps = -kk * (ga * mx + gb * my) * im2, g_pt = -kk * (gc * mx + gd * my) * im2;
    float g_m = kk * (-(ga * psx + gb * psy + gc * ptx + gd * pty) * im2
                      + 2.0 * ((ga * sc + gc * tc) * mx + (gb * sc + gd * tc) * my) * im2 * im);
    p.dlevel_da[2 * ax.x] += float(sg.x) * g_psx; p.dlevel_da[2 * ax.x + 1] += float(sg.x) * g_psy;
    p.dlevel_da[2 * ax.y] += float(sg.y) * g_ptx; p.dlevel_da[2 * ax.y + 1] += float(sg.y) * g_pty;
    p.dlevel_da[2 * ax.z] += float(sg.z) * g_mx; p.dlevel_da[2 * ax.z + 1] += float(sg.z) * g_my;
    p.dlevel_duv[ax.x] += float(sg.x) * g_ps;
    p.dlevel_duv[ax.y] += float(sg.y) * g_pt;
    p.dlevel_duv[ax.z] += float(sg.z) * g_m;
#else
    p.dlevel_da[0] = ga * w0; p.dlevel_da[1] = gb * w0;
    p.dlevel_da[2] = gc * h0; p.dlevel_da[3] = gd * h0;
#endif
#endif
#endif
#ifdef HAS_BIAS
    level += texelFetch(bias, int(i)).x;
#endif
    p.live_level = level > 0.0 && level < float(top);
    level = clamp(level, 0.0, float(top));
#if FILTER == 2
    int l0 = min(int(floor(level + 0.5)), top);
    p.t0 = bilinear(l0, s, t, image, face);
    p.last_level = l0;
#else
    int l0 = min(int(floor(level)), top);
    p.frac = level - float(l0);
    p.t0 = bilinear(l0, s, t, image, face);
    p.t1 = bilinear(min(l0 + 1, top), s, t, image, face);
    p.last_level = min(l0 + 1, top);
#endif
#endif
    return p;
}

// every channel of texel `index` (-1: zeros), CHANNELS / TEXEL_VEC fetches
void fetch_texel(int index, out float v[CHANNELS]) {
    const int fetches = CHANNELS / TEXEL_VEC;
    for (int q = 0; q < fetches; ++q) {
        vec4 f = index < 0 ? vec4(0.0) : texelFetch(texels, index * fetches + q);
        for (int e = 0; e < TEXEL_VEC; ++e) v[q * TEXEL_VEC + e] = f[e];
    }
}

#ifdef BACKWARD
#include "include/atomic_add_float.glsl"

float g_pixel[CHANNELS];  // this pixel's dL/d out, read once

#ifdef ACCUM_FIXED_POINT
// the texel sums are 64-bit fixed-point integers (include/fixed_point.glsl, one group and no
// header: value n at words 2n, 2n + 1, biased by 2^31; each |term| < 2^31: one atomic as a rule); integer addition is associative, so the total is the
// same whatever order the invocations reach it (bit-identical runs), and adding terms in
// the invocation first (fixed_point_add) gives the same words as adding each on its own
#include "include/fixed_point.glsl"
#define TERM uvec2
#define TERM_ZERO uvec2(0u)
#else
#define TERM float
#define TERM_ZERO 0.0
#endif

// The texel terms of one level of one pixel, held back so that the next pixel of the
// invocation can add its own to the texels both read (neighbouring pixels share taps
// wherever the texture is magnified or near 1:1): a texel's sum leaves the invocation, with
// one atomic add per channel, when the pixel that follows no longer reads it. index -1:
// no texel.
struct Held { ivec4 index; TERM v[4][CHANNELS]; };

Held held_none() {
    Held h;
    h.index = ivec4(-1);
    for (int k = 0; k < 4; ++k)
        for (int c = 0; c < channels; ++c) h.v[k][c] = TERM_ZERO;
    return h;
}

// one tap's terms w dL/d out_c (fixed point: round(w g_c 2^k), 2^k = a b in float range)
void tap_terms(inout Held h, int k, int index, float w) {
    h.index[k] = (w == 0.0) ? -1 : index;
    for (int c = 0; c < channels; ++c) {
        float value = w * g_pixel[c];
#ifdef ACCUM_FIXED_POINT
        h.v[k][c] = fixed_point_words(value * fixed_scale_a, fixed_scale_b);
#else
        h.v[k][c] = value;
#endif
    }
}

void send(int index, TERM v[CHANNELS]) {
#ifdef TEX_GRAD
    if (index < 0) return;
    for (int c = 0; c < channels; ++c) {
#ifdef ACCUM_FIXED_POINT
        FIXED_ADD_WORDS(grad_tex, 0u, uint(index * channels + c), v[c]);
#else
        if (v[c] != 0.0) ATOMIC_ADD_FLOAT(grad_tex[index * channels + c], v[c]);
#endif
    }
#endif
}

// `now` (this pixel's terms) takes over the held terms of each texel it reads too (each
// held tap goes to at most one of its taps), and the held taps it does not read are sent
void pass_on(inout Held held, inout Held now) {
    bvec4 kept = bvec4(false);
    for (int k = 0; k < 4; ++k) {
        if (now.index[k] < 0) continue;
        for (int m = 0; m < 4; ++m) {
            if (kept[m] || held.index[m] != now.index[k]) continue;
            kept[m] = true;
            for (int c = 0; c < channels; ++c) {
#ifdef ACCUM_FIXED_POINT
                now.v[k][c] = fixed_point_add(now.v[k][c], held.v[m][c]);
#else
                now.v[k][c] += held.v[m][c];
#endif
            }
        }
    }
    for (int m = 0; m < 4; ++m)
        if (!kept[m]) send(held.index[m], held.v[m]);
    held = now;
}

void send_all(Held h) {
    for (int m = 0; m < 4; ++m) send(h.index[m], h.v[m]);
}

// sum_c g_c texel(index, c): the gradient of the loss by the tap's weight
float tap_gradient(int index) {
    if (index < 0) return 0.0;
    float v[CHANNELS];
    fetch_texel(index, v);
    float r = 0.0;
    for (int c = 0; c < channels; ++c) r += g_pixel[c] * v[c];
    return r;
}

// pixel i's gradients to uv, uv_da, the bias (written), its texel terms passed on to the
// held ones of its levels (level 0 only for the filters without a second level)
void backward_pixel(uint i, inout Held held0, inout Held held1) {
    int image = tex_batch == 1 ? 0 : quotient(int(first_pixel + i), int(pixels_per_image));
    Pixel p = setup(i, image);
    for (int q = 0; q < CHANNELS / TEXEL_VEC; ++q) {
        vec4 f = texelFetch(grad_out, int(i) * (CHANNELS / TEXEL_VEC) + q);
        for (int e = 0; e < TEXEL_VEC; ++e) g_pixel[q * TEXEL_VEC + e] = f[e];
    }
#if defined(TEX_GRAD) && MIP
    // a plain read first: once the maximum is known, few invocations reach the atomic
    if (p.ok && p.last_level > top_level_read) atomicMax(top_level_read, p.last_level);
#endif
    float gs = 0.0, gt = 0.0, glevel = 0.0;
#ifdef TEX_GRAD
    Held now = held_none();
#endif
#if FILTER == 0
#ifdef TEX_GRAD
    if (p.ok) tap_terms(now, 0, p.nearest, 1.0);
    pass_on(held0, now);
#endif
#else
    float w0 = FILTER == 3 ? 1.0 - p.frac : 1.0;
    float s0 = 0.0, s1 = 0.0;
    float ok = p.ok ? 1.0 : 0.0;
    for (int k = 0; k < 4; ++k) {
#ifdef COORD_GRAD
        float tg = tap_gradient(p.t0.index[k]);
        gs += p.t0.ds[k] * tg; gt += p.t0.dt[k] * tg;
        s0 += p.t0.w[k] * tg;
#endif
#ifdef TEX_GRAD
        tap_terms(now, k, p.t0.index[k], ok * w0 * p.t0.w[k]);
#endif
    }
#ifdef TEX_GRAD
    pass_on(held0, now);
#endif
    gs *= w0; gt *= w0;
#if FILTER == 3
    float gs1 = 0.0, gt1 = 0.0;
    for (int k = 0; k < 4; ++k) {
#ifdef COORD_GRAD
        float tg = tap_gradient(p.t1.index[k]);
        gs1 += p.t1.ds[k] * tg; gt1 += p.t1.dt[k] * tg;
        s1 += p.t1.w[k] * tg;
#endif
#ifdef TEX_GRAD
        tap_terms(now, k, p.t1.index[k], ok * p.frac * p.t1.w[k]);
#endif
    }
#ifdef TEX_GRAD
    pass_on(held1, now);
#endif
    gs += p.frac * gs1; gt += p.frac * gt1;
    glevel = p.live_level ? s1 - s0 : 0.0;
#endif
#endif
#ifdef COORD_GRAD
    if (!p.ok) { gs = 0.0; gt = 0.0; glevel = 0.0; }
#if BOUNDARY == 3
    vec3 gd = gs * p.ds_duv + gt * p.dt_duv + glevel * p.dlevel_duv;
    grad_uv[3u * i] = gd.x; grad_uv[3u * i + 1u] = gd.y; grad_uv[3u * i + 2u] = gd.z;
#else
    grad_uv[i] = vec2(gs, gt);   // nearest: no COORD_GRAD (texture.py fills zeros)
#endif
#ifdef HAS_DA
#if NCOORD == 2
    grad_da[i] = glevel * vec4(p.dlevel_da[0], p.dlevel_da[1], p.dlevel_da[2], p.dlevel_da[3]);
#else
    for (int k = 0; k < 2 * NCOORD; ++k)
        grad_da[uint(2 * NCOORD) * i + uint(k)] = glevel * p.dlevel_da[k];
#endif
#endif
#ifdef HAS_BIAS
    grad_bias[i] = glevel;
#endif
#endif
}
#endif

void main() {
#ifndef BACKWARD
    uint i = gl_GlobalInvocationID.x;
    if (i >= n_pixels) return;
    int image = tex_batch == 1 ? 0 : quotient(int(first_pixel + i), int(pixels_per_image));
    Pixel p = setup(i, image);
    // the same products and sums, in the same order, as channel by channel
    float v[CHANNELS], t[CHANNELS];
#if FILTER == 0
    fetch_texel(p.nearest, v);
#else
    for (int c = 0; c < channels; ++c) v[c] = 0.0;
    for (int k = 0; k < 4; ++k) {
        fetch_texel(p.t0.index[k], t);
        for (int c = 0; c < channels; ++c) v[c] += p.t0.w[k] * t[c];
    }
#if FILTER == 3
    float v1[CHANNELS];
    for (int c = 0; c < channels; ++c) v1[c] = 0.0;
    for (int k = 0; k < 4; ++k) {
        fetch_texel(p.t1.index[k], t);
        for (int c = 0; c < channels; ++c) v1[c] += p.t1.w[k] * t[c];
    }
    for (int c = 0; c < channels; ++c) v[c] = v[c] + p.frac * (v1[c] - v[c]);
#endif
#endif
#if CHANNELS == 4
    out_tex[i] = p.ok ? vec4(v[0], v[1], v[2], v[3]) : vec4(0.0);
#else
    for (int c = 0; c < channels; ++c) out_tex[i * uint(channels) + uint(c)] = p.ok ? v[c] : 0.0;
#endif
#else
    // RUN consecutive pixels (along a row of the image) per invocation
    uint first = gl_GlobalInvocationID.x * uint(RUN);
    if (first >= n_pixels) return;
    uint last = min(first + uint(RUN), n_pixels);
#ifdef TEX_GRAD
    Held held0 = held_none(), held1 = held_none();
#else
    Held held0, held1;
#endif
    for (uint i = first; i < last; ++i) backward_pixel(i, held0, held1);
#ifdef TEX_GRAD
    send_all(held0);
#if FILTER == 3
    send_all(held1);
#endif
#endif
#endif
}
