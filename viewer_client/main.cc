// cutsim-viewer: watches a session's mesh over DDS and renders it offscreen.
#include <cstdio>
#include <exception>

#include "common/core/error.h"
#include "viewer_client/viewer_app.h"

int main(int argc, char** argv) {
  try {
    cutsim::viewer::ViewerApp app;
    if (const int code = app.ParseArgs(argc, argv); code >= 0) return code;
    return app.Run();
  } catch (const cutsim::InputError& e) {
    std::fprintf(stderr, "cutsim-viewer: error: %s\n", e.what());
    return 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "cutsim-viewer: fatal: %s\n", e.what());
    return 1;
  }
}
