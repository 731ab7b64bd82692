#include "common/render/osmesa_context.h"

#include <GL/gl.h>
#include <GL/osmesa.h>
#include <fmt/format.h>

#include <stdexcept>

#include "common/core/error.h"

namespace cutsim::render {

OsMesaContext::OsMesaContext(int width, int height) : width_(width), height_(height) {
  if (width < 1 || width > kMaxSize) {
    ThrowInputError(SourceRef{.field = "render.width"},
                    fmt::format("{} is outside [1, {}] pixels", width, kMaxSize));
  }
  if (height < 1 || height > kMaxSize) {
    ThrowInputError(SourceRef{.field = "render.height"},
                    fmt::format("{} is outside [1, {}] pixels", height, kMaxSize));
  }
  buffer_.assign(static_cast<size_t>(width) * static_cast<size_t>(height) * 4, 0);
  context_ = OSMesaCreateContextExt(OSMESA_RGBA, /*depthBits=*/24, /*stencilBits=*/0,
                                    /*accumBits=*/0, /*sharelist=*/nullptr);
  if (context_ == nullptr) {
    throw std::runtime_error(
        fmt::format("OSMesaCreateContextExt(OSMESA_RGBA, 24-bit depth) failed for a {}x{} buffer; "
                    "is Mesa's libOSMesa (libosmesa6) installed and working?",
                    width, height));
  }
  try {
    MakeCurrent();
  } catch (...) {
    OSMesaDestroyContext(context_);
    throw;
  }
}

OsMesaContext::~OsMesaContext() {
  // Unbind first so no thread is left with a dangling current context.
  if (OSMesaGetCurrentContext() == context_) {
    OSMesaMakeCurrent(nullptr, nullptr, 0, 0, 0);
  }
  OSMesaDestroyContext(context_);
}

void OsMesaContext::MakeCurrent() {
  if (OSMesaGetCurrentContext() == context_) return;
  if (OSMesaMakeCurrent(context_, buffer_.data(), GL_UNSIGNED_BYTE, width_, height_) != GL_TRUE) {
    throw std::runtime_error(
        fmt::format("OSMesaMakeCurrent failed for a {}x{} RGBA buffer", width_, height_));
  }
}

Image OsMesaContext::ReadImage() {
  MakeCurrent();
  glFinish();  // OSMesa copies rendering into buffer_ on finish/flush
  Image image;
  image.width = width_;
  image.height = height_;
  image.rgba.resize(buffer_.size());
  const size_t row_bytes = static_cast<size_t>(width_) * 4;
  for (int y = 0; y < height_; ++y) {
    // buffer_ is bottom-up (OSMESA_Y_UP default); Image is top-down.
    const uint8_t* src = buffer_.data() + static_cast<size_t>(height_ - 1 - y) * row_bytes;
    uint8_t* dst = image.rgba.data() + static_cast<size_t>(y) * row_bytes;
    for (size_t i = 0; i < row_bytes; i += 4) {
      dst[i] = src[i];
      dst[i + 1] = src[i + 1];
      dst[i + 2] = src[i + 2];
      dst[i + 3] = 255;
    }
  }
  return image;
}

}  // namespace cutsim::render
