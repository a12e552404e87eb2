# Cross-compiling for 64-bit ARM Linux (boards, phones' Linux userlands) with Debian's cross
# toolchain (crossbuild-essential-arm64) against a sysroot of Debian's arm64 packages unpacked
# without installing them (scripts/portability/arm64.sh: Vulkan loader and headers, lavapipe, OpenImageIO,
# GoogleTest, ...). Tests and programs run under qemu-user (CMAKE_CROSSCOMPILING_EMULATOR).
#   cmake -S . -B build-arm64 -DCMAKE_TOOLCHAIN_FILE=cmake/aarch64-linux-gnu.cmake -DSPAR_ARM64_SYSROOT=DIR
set(CMAKE_SYSTEM_NAME Linux)
set(CMAKE_SYSTEM_PROCESSOR aarch64)
set(CMAKE_C_COMPILER aarch64-linux-gnu-gcc)
set(CMAKE_CXX_COMPILER aarch64-linux-gnu-g++)
if(NOT SPAR_ARM64_SYSROOT)
  set(SPAR_ARM64_SYSROOT "$ENV{SPAR_ARM64_SYSROOT}")
endif()
if(NOT IS_DIRECTORY "${SPAR_ARM64_SYSROOT}/usr/include")
  message(FATAL_ERROR "SPAR_ARM64_SYSROOT='${SPAR_ARM64_SYSROOT}' is not an arm64 sysroot (bash scripts/portability/arm64.sh setup)")
endif()
# Passed on to try_compile projects (the compiler checks), which read this file again.
list(APPEND CMAKE_TRY_COMPILE_PLATFORM_VARIABLES SPAR_ARM64_SYSROOT)
set(CMAKE_SYSROOT "${SPAR_ARM64_SYSROOT}")
set(CMAKE_FIND_ROOT_PATH "${SPAR_ARM64_SYSROOT}")
# Libraries, headers and CMake packages from the sysroot only; programs (glslangValidator,
# python3: build tools) from the host.
set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_PACKAGE ONLY)
# The sysroot's shared libraries' own dependencies, for the linker.
set(_spar_arm64_libs "${SPAR_ARM64_SYSROOT}/usr/lib/aarch64-linux-gnu:${SPAR_ARM64_SYSROOT}/lib/aarch64-linux-gnu")
string(APPEND CMAKE_EXE_LINKER_FLAGS_INIT " -Wl,-rpath-link,${_spar_arm64_libs}")
string(APPEND CMAKE_SHARED_LINKER_FLAGS_INIT " -Wl,-rpath-link,${_spar_arm64_libs}")
# Programs and tests run under qemu-user with the sysroot as their root (/lib, /usr/lib).
find_program(SPAR_QEMU_AARCH64 qemu-aarch64 REQUIRED)
set(CMAKE_CROSSCOMPILING_EMULATOR "${SPAR_QEMU_AARCH64};-L;${SPAR_ARM64_SYSROOT}")
