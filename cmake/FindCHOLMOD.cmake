# FindCHOLMOD: SuiteSparse's sparse Cholesky (Debian: libsuitesparse-dev),
# which ships no CMake package file in SuiteSparse 5.
#
# Defines the imported target CHOLMOD::CHOLMOD (include directory
# <prefix>/include, so sources include <suitesparse/cholmod.h>) and
# CHOLMOD_FOUND. CHOLMOD brings its BLAS and LAPACK through its own shared
# library dependencies (libblas.so.3, which Debian's alternatives point at
# OpenBLAS when libopenblas-dev is installed).
find_path(CHOLMOD_INCLUDE_DIR suitesparse/cholmod.h)
find_library(CHOLMOD_LIBRARY cholmod)
find_library(SUITESPARSE_CONFIG_LIBRARY suitesparseconfig)

include(FindPackageHandleStandardArgs)
find_package_handle_standard_args(CHOLMOD
  REQUIRED_VARS CHOLMOD_LIBRARY SUITESPARSE_CONFIG_LIBRARY CHOLMOD_INCLUDE_DIR)

if(CHOLMOD_FOUND AND NOT TARGET CHOLMOD::CHOLMOD)
  add_library(CHOLMOD::CHOLMOD UNKNOWN IMPORTED)
  set_target_properties(CHOLMOD::CHOLMOD PROPERTIES
    IMPORTED_LOCATION "${CHOLMOD_LIBRARY}"
    INTERFACE_INCLUDE_DIRECTORIES "${CHOLMOD_INCLUDE_DIR}"
    INTERFACE_LINK_LIBRARIES "${SUITESPARSE_CONFIG_LIBRARY};${CMAKE_DL_LIBS}")
endif()
mark_as_advanced(CHOLMOD_INCLUDE_DIR CHOLMOD_LIBRARY SUITESPARSE_CONFIG_LIBRARY)
