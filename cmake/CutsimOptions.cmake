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

if(CUTSIM_NATIVE)
  add_compile_options(-march=native)
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
