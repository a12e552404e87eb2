// spar::Context (include/spar/context.h): owns the engine.
#include "api/api_impl.h"

namespace spar {

Context::Context(const EngineOptions& options) : impl_(std::make_unique<Impl>(options)) {}
Context::~Context() = default;

std::vector<std::string> Context::listDevices() { return Device::listDevices(); }

std::string Context::deviceName() const { return impl_->engine.caps().name; }

uint64_t Context::validationMessages() const { return impl_->engine.device().validationMessageCount(); }

}  // namespace spar
