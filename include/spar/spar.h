// SPAR on Vulkan: the whole public interface (link spar::spar; pkg-config spar).
#pragma once
#include "spar/cameras.h"
#include "spar/context.h"
#include "spar/engine_options.h"
#include "spar/error.h"
#include "spar/images.h"
#include "spar/model.h"
#include "spar/request.h"
#include "spar/session.h"
