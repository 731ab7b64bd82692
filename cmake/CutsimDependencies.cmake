# Every dependency comes from Debian 12 (deploy/install-deps.sh installs them).

find_package(Eigen3 3.4 REQUIRED NO_MODULE)
find_package(spdlog REQUIRED)
find_package(fmt REQUIRED)
find_package(CLI11 REQUIRED)
find_package(OpenMP REQUIRED COMPONENTS CXX)
find_package(Threads REQUIRED)

# Protobuf 3.21 in Debian ships no CMake config: CMake's FindProtobuf module.
find_package(Protobuf REQUIRED)

# Cyclone DDS ships CycloneDDSConfig.cmake with idlc_generate().
find_package(CycloneDDS REQUIRED)

# LCM: lcm.pc requires glib's pkg-config file; link the library directly so
# the build does not depend on glib-dev being present.
find_path(LCM_INCLUDE_DIR lcm/lcm.h REQUIRED)
find_library(LCM_LIBRARY lcm REQUIRED)
add_library(cutsim_lcm INTERFACE)
add_library(cutsim::lcm_c ALIAS cutsim_lcm)
target_include_directories(cutsim_lcm SYSTEM INTERFACE ${LCM_INCLUDE_DIR})
target_link_libraries(cutsim_lcm INTERFACE ${LCM_LIBRARY})

# OpenSSL's libcrypto (libssl-dev): HMAC-SHA256 of tool messages (tool_auth.h).
find_package(OpenSSL 3 REQUIRED COMPONENTS Crypto)

# SQLite 3 (libsqlite3-dev): the lab's score history per trainee (common/record).
find_package(SQLite3 REQUIRED)

# Browser observers' HTTP/WebSocket server: Boost.Beast over Boost.Asio
# (header-only in Boost 1.74; common/net compiles their sources once).
find_package(Boost 1.74 REQUIRED)

# gmsh (libgmsh-dev): .msh reading/writing and surface tetrahedralisation.
find_path(GMSH_INCLUDE_DIR gmsh.h REQUIRED)
find_library(GMSH_LIBRARY gmsh REQUIRED)
add_library(cutsim_gmsh INTERFACE)
add_library(cutsim::gmsh_api ALIAS cutsim_gmsh)
target_include_directories(cutsim_gmsh SYSTEM INTERFACE ${GMSH_INCLUDE_DIR})
target_link_libraries(cutsim_gmsh INTERFACE ${GMSH_LIBRARY})

# OSMesa for offscreen rendering; libpng for image output.
find_package(PkgConfig REQUIRED)
pkg_check_modules(OSMESA IMPORTED_TARGET osmesa)
find_package(PNG REQUIRED)

if(CUTSIM_BUILD_TESTS)
  find_package(GTest REQUIRED)
  include(GoogleTest)
endif()
if(CUTSIM_BUILD_BENCH)
  find_package(benchmark REQUIRED)
endif()
