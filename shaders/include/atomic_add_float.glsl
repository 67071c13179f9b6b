// ATOMIC_ADD_FLOAT(word, value): word += value as one atomic float addition on a
// storage-buffer element, for the backward passes' gradient sums.
//   ACCUM_ATOMIC_FLOAT: `word` is a float and this is atomicAdd
//                       (GL_NV_shader_atomic_float: the shader enables the extension);
//   ACCUM_CAS:          `word` is a uint holding the float's bits, and the sum is retried
//                       with atomicCompSwap until no other invocation wrote in between
//                       (GLSL 4.50 section 8.11).
// `word` is evaluated more than once: pass an element expression without side effects.
// Macros only (no declarations), so it may be included anywhere.

#if defined(ACCUM_ATOMIC_FLOAT)
#define ATOMIC_ADD_FLOAT(word, value) atomicAdd(word, value)
#elif defined(ACCUM_CAS)
#define ATOMIC_ADD_FLOAT(word, value) {                                            \
    float added_ = (value);                                                        \
    uint seen_ = word;                                                             \
    while (true) {                                                                 \
        uint got_ = atomicCompSwap(word, seen_,                                    \
                                   floatBitsToUint(uintBitsToFloat(seen_) + added_)); \
        if (got_ == seen_) break;                                                  \
        seen_ = got_;                                                              \
    }                                                                              \
}
#endif
