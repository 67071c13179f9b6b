#version 450
// Antialias, pass 1: the blended pixel pairs. One invocation per listed candidate pair
// (pair_list[i] = 2 A + axis, A = (b, y, x) flat in the chunk, B = A + (1, 0) or (0, 1):
// the pairs whose triangle ids differ, listed by the host); it writes the pair's record
// records[2 A + axis] = (code + 4 i, row_a, row_b, bits of tau) (nobody clears the rest):
//   code 0: no blend; 1: A takes alpha = 1/2 - tau of B's colour; 2: B takes tau - 1/2 of A's;
//   i: the pair's place in the list
//   row_a, row_b: the pos rows (batch offset included) of the crossing edge's vertices
//   tau: where the edge crosses the segment from A's centre (0) to B's (1)
// The model and its float64 twin: glraster/diff/antialias_reference.py (docs/differentiable.md,
// "Antialias"). Everything is evaluated in the frame of A's centre,
//   v'_j = ((W/2)(x_j - w_j n_x), (H/2)(y_j - w_j n_y), w_j),   n = A's centre in NDC,
// where the row r_i = v'_{i+1} x v'_{i+2} of triangle edge i has the edge function at A as
// its third component and at B = A + d that plus r_i[axis]; s_i = e_i / det > 0 inside.

layout(local_size_x = 64) in;

layout(std430, binding = 0) readonly buffer Pos { vec4 pos[]; };
layout(std430, binding = 1) readonly buffer Tri { int tri[]; };
layout(std430, binding = 2) readonly buffer Rast { vec4 rast[]; };
layout(std430, binding = 3) readonly buffer Table { uvec4 table[]; };   // (lo, hi, start, count)
layout(std430, binding = 4) readonly buffer Entries { int entries[]; };  // 3 t + i
layout(std430, binding = 5) readonly buffer Canon { int canon[]; };
layout(std430, binding = 6) writeonly buffer Records { uvec4 records[]; };
layout(std430, binding = 7) readonly buffer PairList { uint pair_list[]; };

uniform uint n_pairs;        // listed pairs in this dispatch (whole images)
uniform uint first_image;    // batch index of the chunk's first image
uniform ivec2 size;          // (W, H)
uniform uint vertex_stride;  // V when pos is batched, else 0
uniform int n_tri;
uniform uint table_mask;     // slots - 1 (a power of two minus one)

#ifndef MAX_WALK
#define MAX_WALK 8
#endif

#include "include/triangle_id.glsl"
#include "include/frame.glsl"

// The run (start, count) of opposite vertices of edge (lo, hi), lo <= hi: linear probing
// from the slot the host's table was built with (antialias_reference._hash).
bool find_edge(uint lo, uint hi, out uint start, out uint count) {
    uint h = (lo * 0x9E3779B1u) ^ (hi * 0x85EBCA77u);
    h ^= h >> 15;
    uint s = h & table_mask;
    start = 0u;
    count = 0u;
    for (uint probe = 0u; probe <= table_mask; ++probe) {
        uvec4 e = table[s];
        if (e.x == 0xFFFFFFFFu) return false;
        if (e.x == lo && e.y == hi) {
            start = e.z;
            count = e.w;
            return true;
        }
        s = (s + 1u) & table_mask;
    }
    return false;
}

bool opposite_signs(float a, float b) {
    return (a < 0.0 && b > 0.0) || (a > 0.0 && b < 0.0);
}

// The walk (antialias_reference.pairs): from the candidate pixel's centre towards the
// other's, leave the current triangle through the first edge crossed; continue in a
// triangle sharing that edge and lying beyond it, else that edge is the silhouette.
uvec4 eval_pair(uint ia, uint ib, uint xa, uint ya, int axis, uint vbase) {
    vec4 RA = rast[ia], RB = rast[ib];
    int tA = decode_id(RA.w) - 1, tB = decode_id(RB.w) - 1;
    if (tA == tB) return uvec4(0u);
    // the nearer pixel's triangle first (an empty pixel is never nearer; ties: A)
    bool ownA = tB < 0 || (tA >= 0 && !(RB.z < RA.z));
    vec2 n = vec2(float(2u * xa + 1u) / float(size.x) - 1.0,
                  float(2u * ya + 1u) / float(size.y) - 1.0);
    int t = ownA ? tA : tB;
    int entry = -1;
    int step = 0;
    bool retried = false;
    while (true) {
        if (t < 0 || t >= n_tri) return uvec4(0u);
        int vi[3] = int[3](tri[3 * t], tri[3 * t + 1], tri[3 * t + 2]);
        vec3 v[3];
        for (int j = 0; j < 3; ++j) v[j] = frame_vertex(pos[vbase + uint(vi[j])], n, size);
        vec3 r[3];
        for (int i = 0; i < 3; ++i) r[i] = cross(v[(i + 1) % 3], v[(i + 2) % 3]);
        float det = dot(r[0], v[0]);
        int best = -1;
        float best_key = 0.0, best_other = 0.0;
        for (int i = 0; i < 3; ++i) {
            float ea = r[i].z;
            float eb = ea + r[i][axis];
            float own = det > 0.0 ? (ownA ? ea : eb) : -(ownA ? ea : eb);
            float other = det > 0.0 ? (ownA ? eb : ea) : -(ownA ? eb : ea);
            bool leaving = own > other && det != 0.0 && i != entry && (step > 0 || own >= 0.0);
            if (leaving) {
                float tau_i = -ea / r[i][axis];
                float key = ownA ? tau_i : -tau_i;
                if (best < 0 || key < best_key) {
                    best = i;
                    best_key = key;
                    best_other = other;
                }
            }
        }
        if (best < 0 || best_other >= 0.0) {
            // the walk reached the other centre: a continuous surface; from the first
            // triangle, try the other pixel's instead
            if (step == 0 && !retried) {
                retried = true;
                ownA = !ownA;
                t = ownA ? tA : tB;
                entry = -1;
                continue;
            }
            return uvec4(0u);
        }
        int a = vi[(best + 1) % 3], b = vi[(best + 2) % 3], o = vi[best];
        vec3 rl = r[best];
        float dF = dot(rl, v[best]);
        int ca = canon[a], cb = canon[b], co = canon[o];
        int next = -1, next_slot = -1;
        uint start, count;
        if (find_edge(uint(min(ca, cb)), uint(max(ca, cb)), start, count)) {
            for (uint k = 0u; k < count; ++k) {
                int e = entries[start + k];
                int og = tri[e];
                if (canon[og] == co) continue;
                float dG = dot(rl, frame_vertex(pos[vbase + uint(og)], n, size));
                if (opposite_signs(dG, dF)) {
                    next = e / 3;
                    next_slot = e % 3;
                    break;
                }
            }
        }
        if (next < 0) {
            // the silhouette; the pair's axis must be the one most across it
            vec3 rs = cross(frame_vertex(pos[vbase + uint(a)], n, size),
                            frame_vertex(pos[vbase + uint(b)], n, size));
            float tau = -rs.z / rs[axis];
            float across = abs(rs[axis]), along = abs(rs[1 - axis]);
            if (axis == 0 ? !(across >= along) : !(across > along)) return uvec4(0u);
            return uvec4(tau < 0.5 ? 1u : 2u, vbase + uint(a), vbase + uint(b),
                         floatBitsToUint(tau));
        }
        t = next;
        entry = next_slot;
        step += 1;
        if (step >= MAX_WALK) return uvec4(0u);
    }
    return uvec4(0u);
}

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= n_pairs) return;
    uint code = pair_list[i];
    uint A = code >> 1;
    int axis = int(code & 1u);
    uint W = uint(size.x), H = uint(size.y);
    uint hw = W * H;
    uint image = A / hw, pix = A % hw;
    uint y = pix / W, x = pix % W;
    uint vbase = (first_image + image) * vertex_stride;
    uvec4 rec = eval_pair(A, axis == 0 ? A + 1u : A + W, x, y, axis, vbase);
    if (rec.x != 0u) rec.x += 4u * i;
    records[code] = rec;
}
