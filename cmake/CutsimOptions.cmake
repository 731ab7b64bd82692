# Compiler flags shared by every cutsim target, as INTERFACE targets that the
# libraries link PRIVATE, so consumers never inherit our warning policy.

add_library(cutsim_warnings INTERFACE)
add_library(cutsim::warnings ALIAS cutsim_warnings)
target_compile_options(cutsim_warnings INTERFACE
  -Wall -Wextra -Wpedantic -Wshadow -Wnon-virtual-dtor -Wold-style-cast
  -Wcast-align -Wunused -Woverloaded-virtual
  -Wdouble-promotion -Wformat=2 -Wimplicit-fallthrough
  -Wno-missing-field-initializers)
if(CUTSIM_WERROR)
  target_compile_options(cutsim_warnings INTERFACE -Werror)
endif()
# A unity build (CMAKE_UNITY_BUILD, the test presets) includes each source
# file into a batch file, so GCC takes a file's anonymous-namespace types as
# a header's and warns when a class of the file holds one.
if(CMAKE_UNITY_BUILD AND CMAKE_CXX_COMPILER_ID STREQUAL "GNU")
  target_compile_options(cutsim_warnings INTERFACE -Wno-subobject-linkage)
endif()

if(CUTSIM_NATIVE)
  add_compile_options(-march=native)
endif()

# The linker, as the compiler driver's -fuse-ld= (empty: the toolchain's
# default, GNU ld). The test presets (ci, asan, fuzz) set lld: it links the
# test executables, each of which pulls in most of the static libraries with
# their debug line tables, in about a third of GNU ld's CPU time.
set(CUTSIM_LINKER "" CACHE STRING "Linker for -fuse-ld= (lld, gold, ...); empty: the toolchain's default")
if(CUTSIM_LINKER)
  include(CheckLinkerFlag)
  check_linker_flag(CXX -fuse-ld=${CUTSIM_LINKER} CUTSIM_LINKER_WORKS)
  if(NOT CUTSIM_LINKER_WORKS)
    message(FATAL_ERROR "CUTSIM_LINKER=${CUTSIM_LINKER}: the compiler cannot link with it (deploy/install-deps.sh installs lld)")
  endif()
  add_link_options(-fuse-ld=${CUTSIM_LINKER})
endif()

if(CUTSIM_SANITIZE)
  add_compile_options(-fsanitize=address,undefined -fno-sanitize-recover=undefined
                      -fno-omit-frame-pointer)
  add_link_options(-fsanitize=address,undefined)
endif()

# libFuzzer: every object is instrumented for coverage and checked by ASan and
# UBSan; the fuzz_* executables add the libFuzzer driver (tests/fuzz).
if(CUTSIM_FUZZ)
  if(NOT CMAKE_CXX_COMPILER_ID MATCHES "Clang")
    message(FATAL_ERROR "CUTSIM_FUZZ needs clang (the fuzz preset sets it; Debian package clang)")
  endif()
  add_compile_options(-fsanitize=fuzzer-no-link,address,undefined -fno-sanitize-recover=undefined
                      -fno-omit-frame-pointer)
  add_link_options(-fsanitize=address,undefined)
endif()
