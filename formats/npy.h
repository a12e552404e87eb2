// NumPy .npy files: read and write little-endian '<f4', '<f8', '<i4', '<i8' arrays in C order
// (format versions 1.0, 2.0 and 3.0). The tests read the PyTorch reference's goldens with it.
// Every problem is a spar::Error with a one-line message naming the file.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

namespace spar {

enum class NpyType { F32, F64, I32, I64 };

const char* npyTypeName(NpyType t);  // "<f4", "<f8", "<i4", "<i8"
size_t npyTypeSize(NpyType t);

struct NpyArray {
  NpyType type = NpyType::F32;
  std::vector<int64_t> shape;  // empty: a 0-d array of one element
  std::vector<uint8_t> data;   // numel() * npyTypeSize(type) bytes, little-endian, C order

  int64_t numel() const;
  // The values converted (f64 -> f32 rounds; i64 -> double is exact up to 2^53).
  std::vector<float> toFloats() const;
  std::vector<double> toDoubles() const;
  std::vector<int64_t> toInt64s() const;
};

NpyArray readNpy(const std::string& path);
// Same as readNpy, and throws unless the shape is `shape` exactly.
NpyArray readNpy(const std::string& path, const std::vector<int64_t>& shape);

void writeNpy(const std::string& path, const NpyArray& array);
void writeNpy(const std::string& path, const std::vector<int64_t>& shape, const float* values);
void writeNpy(const std::string& path, const std::vector<int64_t>& shape, const double* values);
void writeNpy(const std::string& path, const std::vector<int64_t>& shape, const int32_t* values);
void writeNpy(const std::string& path, const std::vector<int64_t>& shape, const int64_t* values);

}  // namespace spar
