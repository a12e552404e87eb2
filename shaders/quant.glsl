// Block-quantized weight matrices (converter/FORMAT.md, "Quantized matrices"; engine/tensor.h
// DType::Q8 / Q4), dequantized where a kernel reads them: never expanded in device memory.
// A row of K values is K/32 blocks of codes in 32-bit words (q8: 4 int8 a word, k ascending
// from the low byte; q4: 8 nibbles a word, value = nibble - 8), then its K/32 float32 scales.
// The words come through a uniform texel buffer of R32_UINT texels, or through a storage
// buffer of words in the *_sx twins (STORAGE_INPUTS=1): no 8- or 16-bit storage feature used.
// QUANT_ROW_WORDS(kTexels): the 32-bit words of a row of kTexels * 4 values (its codes, then
// one scale a block of 32; engine/tensor.h rowBytes / 4).
// QUANT_INPUT(BINDING, NAME) declares the binding and
//   vec4 fetchq_NAME(int row, int kk, int kTexels)
// the 4 values k = 4 kk .. 4 kk + 3 of the row whose words start at `row` (kTexels = K / 4),
// for W_BITS (8 or 4, a specialization constant of the including kernel).
#if defined(STORAGE_INPUTS) && STORAGE_INPUTS
#define QUANT_WORDS(BINDING, NAME)                                     \
  layout(binding = BINDING) readonly buffer NAME##_qwords { uint NAME##_q[]; }; \
  uint word_##NAME(int i) { return NAME##_q[i]; }
#else
#define QUANT_WORDS(BINDING, NAME)                          \
  layout(binding = BINDING) uniform utextureBuffer NAME;   \
  uint word_##NAME(int i) { return texelFetch(NAME, i).x; }
#endif

#define QUANT_ROW_WORDS(kTexels) ((W_BITS == 8 ? (kTexels) : (kTexels) / 2) + (kTexels) / 8)

#define QUANT_INPUT(BINDING, NAME)                                                               \
  QUANT_WORDS(BINDING, NAME)                                                                     \
  vec4 fetchq_##NAME(int row, int kk, int kTexels) {                                             \
    const int codeWords = W_BITS == 8 ? kTexels : kTexels / 2;                                   \
    const float s = uintBitsToFloat(word_##NAME(row + codeWords + (kk >> 3)));                   \
    if (W_BITS == 8) {                                                                           \
      const int w = int(word_##NAME(row + kk));                                                  \
      return vec4((w << 24) >> 24, (w << 16) >> 24, (w << 8) >> 24, w >> 24) * s;               \
    }                                                                                            \
    const uint w = word_##NAME(row + (kk >> 1)) >> (16 * (kk & 1));                             \
    return (vec4(uvec4(w, w >> 4, w >> 8, w >> 12) & 0xFu) - 8.0) * s;                           \
  }
