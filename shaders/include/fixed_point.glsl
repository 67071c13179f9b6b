// Order-independent fixed-point sums (ACCUM_FIXED_POINT; the host side is
// glraster.diff.compute.FixedPointSum, whose docstring states the range and rounding).
//
// The accumulator is a uint storage buffer `buf`:
//   buf[g]               g < groups: the largest |term| added to group g (float bits; for
//                        non-negative floats the uint order is the float order, GLSL 4.50
//                        section 8.4, so atomicMax on the bits keeps the maximum; NaN > inf)
//   buf[groups + g]      group g's scale 2^k (float bits, written by the host)
//   buf[2 groups + 2 n]  value n as a 64-bit two's-complement integer: low word, high word,
//                        plus 2^31 (the host fills each pair with (2^31, 0))
// A term t becomes q = roundEven(t 2^k); q is added with one atomicAdd on the low word and,
// when the high part or the carry out of the low word is not zero, one on the high word.
// FixedPointSum's k keeps every |q| <= 2^31, so the high part of a term is 0 or all ones
// and cancels the carry unless the low word's running sum crosses +-2^31 from the bias:
// one atomic a term as a rule. (texture.comp: the same words and bias, without the header.)
// Integer addition is associative and commutative, so every word ends with the same bits
// whatever the order of the additions. Macros only (no declarations) apart from
// fixed_point_words, so the shader declares `buf` with its own binding.

// round(value * scale) as (low, high) words of a 64-bit two's-complement integer, without
// 64-bit arithmetic: |r| < 2^63 has at most 24 significant bits, so its part above 2^32 (h)
// and the rest (r - h 2^32) are both exact in float32 and convert to uint exactly.
uvec2 fixed_point_words(float value, float scale) {
    float r = roundEven(abs(value) * scale);
    float h = floor(r * 2.3283064365386963e-10);   // r / 2^32
    uint hi = uint(h);
    uint lo = uint(r - h * 4294967296.0);
    if (value < 0.0) {                               // -(hi, lo) = ~(hi, lo) + 1
        lo = ~lo + 1u;
        hi = ~hi + (lo == 0u ? 1u : 0u);
    }
    return uvec2(lo, hi);
}

// (low, high) words a + b, mod 2^64
uvec2 fixed_point_add(uvec2 a, uvec2 b) {
    uint lo = a.x + b.x;
    return uvec2(lo, a.y + b.y + (lo < a.x ? 1u : 0u));
}

// buf[..value n..] += q, q given as (low, high) words (e.g. a local sum of rounded terms).
// `buf`, `groups`, `n` are evaluated more than once: pass expressions without side effects.
#define FIXED_ADD_WORDS(buf, groups, n, q) {                                        \
    uvec2 w_ = (q);                                                                 \
    if (w_ != uvec2(0u)) {                                                          \
        uint at_ = 2u * ((groups) + (n));                                           \
        uint old_ = atomicAdd(buf[at_], w_.x);                                      \
        uint high_ = w_.y + (old_ + w_.x < old_ ? 1u : 0u);                         \
        if (high_ != 0u) atomicAdd(buf[at_ + 1u], high_);                           \
    }                                                                               \
}

// the bits of |value| (uint order = float order, NaN above inf: max() on them keeps a NaN,
// where max() on floats may drop it)
uint fixed_point_magnitude(float value) {
    return floatBitsToUint(abs(value));
}

// group g's maximum |term| raised to the float whose bits are `magnitude`
#define FIXED_TRACK(buf, g, magnitude) {                                            \
    uint bits_ = (magnitude);                                                       \
    if (bits_ > buf[g]) atomicMax(buf[g], bits_);                                   \
}

// buf[..value n of group g..] += round(value 2^k_g); records |value| in group g's maximum.
// `buf`, `groups`, `g`, `n` are evaluated more than once: pass expressions without side effects.
#define FIXED_ADD(buf, groups, g, n, value) {                                       \
    float v_ = (value);                                                             \
    FIXED_TRACK(buf, g, fixed_point_magnitude(v_));                                                   \
    FIXED_ADD_WORDS(buf, groups, n,                                                 \
                    fixed_point_words(v_, uintBitsToFloat(buf[(groups) + (g)])));   \
}
