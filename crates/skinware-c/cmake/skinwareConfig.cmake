# find_package(skinware CONFIG) for skinware's C API, installed by
# `cargo cinstall -p skinware-c --prefix PREFIX` (this file lands in
# PREFIX/share/cmake/skinware/). It defines the imported target
# skinware::skinware (the shared library, its include directory, and the
# C++17 wrapper's language level for C++ users):
#
#   find_package(skinware 0.1 CONFIG REQUIRED)
#   target_link_libraries(my_controller PRIVATE skinware::skinware)
#
# Set CMAKE_PREFIX_PATH=PREFIX (or skinware_DIR) when PREFIX is not a system prefix.
get_filename_component(_skinware_prefix "${CMAKE_CURRENT_LIST_DIR}/../../.." ABSOLUTE)

find_path(SKINWARE_INCLUDE_DIR skinware.h
  PATHS "${_skinware_prefix}/include/skinware" NO_DEFAULT_PATH)
find_library(SKINWARE_LIBRARY NAMES skinware
  PATHS "${_skinware_prefix}/lib" "${_skinware_prefix}/lib64" "${_skinware_prefix}/lib/${CMAKE_LIBRARY_ARCHITECTURE}"
  NO_DEFAULT_PATH)

if(NOT SKINWARE_INCLUDE_DIR OR NOT SKINWARE_LIBRARY)
  set(skinware_FOUND FALSE)
  set(skinware_NOT_FOUND_MESSAGE
    "skinware's header or library is missing under ${_skinware_prefix} (include/skinware/skinware.h, lib/libskinware.so); reinstall with `cargo cinstall -p skinware-c --release --prefix ${_skinware_prefix}`")
  return()
endif()

if(NOT TARGET skinware::skinware)
  add_library(skinware::skinware SHARED IMPORTED)
  set_target_properties(skinware::skinware PROPERTIES
    IMPORTED_LOCATION "${SKINWARE_LIBRARY}"
    INTERFACE_INCLUDE_DIRECTORIES "${SKINWARE_INCLUDE_DIR}"
    # The library is Rust: it needs the system's threads, dl, m and rt.
    INTERFACE_LINK_LIBRARIES "pthread;dl;m;rt")
endif()
set(skinware_FOUND TRUE)
unset(_skinware_prefix)
