# OpenImageIO (image files: imaging/, the CLI's GIF, tests), found once for every directory.
# Debian 12's OpenImageIOConfig lists
# /usr/include/opencv4 among OpenImageIO::OpenImageIO's include directories even when OpenCV is not
# installed, which CMake rejects: keep only the directories that exist.
find_package(OpenImageIO CONFIG REQUIRED)
get_target_property(_spar_oiio_includes OpenImageIO::OpenImageIO INTERFACE_INCLUDE_DIRECTORIES)
if(_spar_oiio_includes)
  set(_spar_oiio_existing)
  foreach(_dir IN LISTS _spar_oiio_includes)
    if(EXISTS "${_dir}")
      list(APPEND _spar_oiio_existing "${_dir}")
    endif()
  endforeach()
  set_target_properties(OpenImageIO::OpenImageIO PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_spar_oiio_existing}")
endif()
