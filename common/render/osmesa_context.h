#pragma once
/// @file
/// RAII over an OSMesa (software, offscreen) OpenGL context and its colour
/// buffer. Kept apart from the drawing code so the renderer never touches
/// context management.

#include <cstdint>
#include <vector>

#include "common/render/image.h"

struct osmesa_context;  // OSMesa's opaque context (osmesa.h: OSMesaContext).

namespace cutsim::render {

/// An RGBA8 OSMesa context with a 24-bit depth buffer, rendering into a
/// width×height buffer owned by this object. Neither copyable nor movable
/// (OSMesa keeps the buffer's address); hold it by `std::unique_ptr`.
class OsMesaContext {
 public:
  /// Largest width or height accepted, pixels (Mesa's software limit).
  static constexpr int kMaxSize = 16384;

  /// Creates the context. Throws `InputError` (field "render.width" or
  /// "render.height") for a size outside [1, kMaxSize], and
  /// `std::runtime_error` when OSMesa cannot create or bind the context.
  /// The new context is made current on the calling thread.
  OsMesaContext(int width, int height);
  /// Releases the context (unbinding it first if it is current).
  ~OsMesaContext();

  OsMesaContext(const OsMesaContext&) = delete;
  OsMesaContext& operator=(const OsMesaContext&) = delete;
  OsMesaContext(OsMesaContext&&) = delete;
  OsMesaContext& operator=(OsMesaContext&&) = delete;

  /// Binds this context and its buffer to the calling thread (cheap if it
  /// already is). Throws `std::runtime_error` on failure.
  void MakeCurrent();

  /// Finishes pending GL work and returns the colour buffer as a top-down
  /// image with alpha forced to 255. Makes the context current first.
  [[nodiscard]] Image ReadImage();

  [[nodiscard]] int width() const { return width_; }
  [[nodiscard]] int height() const { return height_; }

 private:
  int width_;                    // pixels
  int height_;                   // pixels
  std::vector<uint8_t> buffer_;  // width·height·4, bottom-up rows (OSMesa's Y-up default)
  osmesa_context* context_ = nullptr;
};

}  // namespace cutsim::render
