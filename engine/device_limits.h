// How a device-limit profile (include/spar/device_limits.h) tightens the capabilities the engine
// read off the device: every limit the smaller, every alignment the larger, a feature the profile
// turns off is off (and is not enabled on the logical device).
#pragma once
#include "engine/device.h"
#include "spar/device_limits.h"

namespace spar {

void tightenCaps(DeviceCaps& caps, const DeviceLimits& limits);

}  // namespace spar
