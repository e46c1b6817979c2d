# Find UMFPACK (SuiteSparse) and define UMFPACK::UMFPACK.
# Debian puts the headers in /usr/include/suitesparse; the library links its own dependencies
# (AMD, CHOLMOD, BLAS) as shared objects, so only libumfpack is named here.
find_path(UMFPACK_INCLUDE_DIR umfpack.h PATH_SUFFIXES suitesparse)
find_library(UMFPACK_LIBRARY NAMES umfpack)
find_library(AMD_LIBRARY NAMES amd)
find_library(SUITESPARSECONFIG_LIBRARY NAMES suitesparseconfig)
include(FindPackageHandleStandardArgs)
find_package_handle_standard_args(UMFPACK REQUIRED_VARS UMFPACK_LIBRARY UMFPACK_INCLUDE_DIR AMD_LIBRARY)
if(UMFPACK_FOUND AND NOT TARGET UMFPACK::UMFPACK)
  add_library(UMFPACK::UMFPACK UNKNOWN IMPORTED)
  set_target_properties(UMFPACK::UMFPACK PROPERTIES
    IMPORTED_LOCATION "${UMFPACK_LIBRARY}"
    INTERFACE_INCLUDE_DIRECTORIES "${UMFPACK_INCLUDE_DIR}"
    INTERFACE_LINK_LIBRARIES "${AMD_LIBRARY};$<$<BOOL:${SUITESPARSECONFIG_LIBRARY}>:${SUITESPARSECONFIG_LIBRARY}>")
endif()
mark_as_advanced(UMFPACK_INCLUDE_DIR UMFPACK_LIBRARY AMD_LIBRARY SUITESPARSECONFIG_LIBRARY)
