// SPAR_API marks what libspar exports; everything else in the library is hidden.
#pragma once

#if defined(_WIN32)
#define SPAR_API
#else
#define SPAR_API __attribute__((visibility("default")))
#endif
