// Error-free transformations for compensated evaluation in the working precision REAL
// (float unless the including shader defines REAL double, with SPLITTER 2^27 + 1).
// `precise` keeps the compiler from contracting or reassociating these operations
// (GLSL 4.50 section 4.7.1).

#ifndef REAL
#define REAL float
#endif
#ifndef SPLITTER
#define SPLITTER 4097.0  // 2^12 + 1: splits a float's 24-bit mantissa in halves
#endif

// hi + lo = a exactly, each with half the mantissa bits (Veltkamp's split).
void split(REAL a, out REAL hi, out REAL lo) {
    precise REAL c = SPLITTER * a;
    precise REAL h = c - (c - a);
    hi = h;
    lo = a - h;
}

// hi + lo = a * b exactly (Dekker's TwoProduct). llvmpipe lowers GLSL fma() to a separate
// multiply and add (measured: fma(a, b, -a b) returns 0), so the product is split instead.
void two_product(REAL a, REAL b, out REAL hi, out REAL lo) {
    precise REAL p = a * b;
    REAL ah, al, bh, bl;
    split(a, ah, al);
    split(b, bh, bl);
    precise REAL err = ((ah * bh - p) + ah * bl + al * bh) + al * bl;
    hi = p;
    lo = err;
}

// hi + lo = a + b exactly (Knuth's TwoSum, no ordering needed).
void two_sum(REAL a, REAL b, out REAL hi, out REAL lo) {
    precise REAL s = a + b;
    precise REAL bb = s - a;
    precise REAL err = (a - (s - bb)) + (b - bb);
    hi = s;
    lo = err;
}

// The plane value s(a) + grad s . d, with s(a) = s_hi + s_lo and each gradient component a
// (hi, lo) pair, d = (dx, dy) exact: the products and the first sums are error-free, their
// errors summed in a tail (Ogita, Rump & Oishi 2005, "Dot2"), so the result is about as
// accurate as if computed in twice the working precision and rounded once.
REAL compensated_plane(REAL gx_hi, REAL gx_lo, REAL gy_hi, REAL gy_lo, REAL s_hi, REAL s_lo,
                       REAL dx, REAL dy) {
    REAL px, ex, py, ey, t, f1, u, f2;
    two_product(gx_hi, dx, px, ex);
    two_product(gy_hi, dy, py, ey);
    two_sum(px, py, t, f1);
    two_sum(t, s_hi, u, f2);
    precise REAL tail = (f1 + f2) + (ex + ey) + s_lo + (gx_lo * dx + gy_lo * dy);
    precise REAL result = u + tail;
    return result;
}
