// cutsim-server: owns the tissue model and the topology of every cut.
#include <cstdio>
#include <exception>
#include <new>

#include "common/core/error.h"
#include "server/server_app.h"

int main(int argc, char** argv) {
  try {
    cutsim::server::ServerApp app;
    if (const int code = app.ParseArgs(argc, argv); code >= 0) return code;
    return app.Run();
  } catch (const cutsim::InputError& e) {
    std::fprintf(stderr, "cutsim-server: error: %s\n", e.what());
    return 2;
  } catch (const std::bad_alloc&) {
    std::fprintf(stderr, "cutsim-server: fatal: out of memory (every input is size-checked: the machine has "
                         "too little memory for this scene)\n");
    return 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "cutsim-server: fatal: %s\n", e.what());
    return 1;
  }
}
