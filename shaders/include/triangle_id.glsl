// Triangle index + 1 as a float32 (channel 3 of the differentiable rasterize's rast; 0 on
// empty pixels), the encoding of glraster/diff/ids.py: the value itself while id <= 2^24
// (every integer up to 2^24 is a float32), above that the float whose bit pattern is
// ID_BIAS + id. The second branch continues the first without a gap and is monotone, so
// ids compare as floats.

#define ID_BIAS 0x4a800000
#define EXACT_FLOAT_IDS 16777216  // 2^24

float encode_id(int id) {
    return id <= EXACT_FLOAT_IDS ? float(id) : intBitsToFloat(ID_BIAS + id);
}

int decode_id(float f) {
    return f <= float(EXACT_FLOAT_IDS) ? int(f) : floatBitsToInt(f) - ID_BIAS;
}
