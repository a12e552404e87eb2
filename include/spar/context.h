// The engine a model runs on: one Vulkan device with its memory and compiled kernels. Create
// one per device and keep it: kernels compiled for one request are reused by the next.
#pragma once
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "spar/engine_options.h"
#include "spar/export.h"

namespace spar {

class SPAR_API Context {
 public:
  // Throws spar::Error when no Vulkan 1.2 device matches (the message lists what was found).
  explicit Context(const EngineOptions& options = EngineOptions::fromEnvironment());
  ~Context();
  Context(const Context&) = delete;
  Context& operator=(const Context&) = delete;

  // "index: name (type)" of every Vulkan device on this machine.
  static std::vector<std::string> listDevices();

  std::string deviceName() const;
  // Messages the validation layer reported so far (EngineOptions::validation; else 0).
  uint64_t validationMessages() const;

  struct Impl;
  Impl& impl() { return *impl_; }

 private:
  std::unique_ptr<Impl> impl_;
};

}  // namespace spar
