#include "common/render/image.h"

#include <fmt/format.h>
#include <png.h>

#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <stdexcept>
#include <system_error>

#include "common/core/error.h"
#include "common/core/input_file.h"
#include "common/render/palette.h"

namespace cutsim::render {
namespace {

struct FileCloser {
  void operator()(std::FILE* f) const { std::fclose(f); }
};
using FilePtr = std::unique_ptr<std::FILE, FileCloser>;

/// Frees a png_image's internal state however the simplified API exited.
struct PngImageGuard {
  png_image* image;
  ~PngImageGuard() { png_image_free(image); }
};

std::string ErrnoText() { return std::generic_category().message(errno); }

}  // namespace

bool Image::valid() const {
  return width > 0 && height > 0 &&
         rgba.size() == static_cast<size_t>(width) * static_cast<size_t>(height) * 4;
}

void WritePng(const std::filesystem::path& path, const Image& image) {
  const std::string name = path.string();
  if (!image.valid()) {
    ThrowFileError(name, fmt::format("cannot write an invalid {}x{} image with {} bytes",
                                     image.width, image.height, image.rgba.size()));
  }
  CheckOutputPath(name, "image");  // the rename below would replace a device or a pipe
  const std::filesystem::path tmp = std::filesystem::path(name + ".tmp");
  {
    FilePtr file(std::fopen(tmp.c_str(), "wb"));
    if (!file) ThrowFileError(name, fmt::format("cannot open for writing: {}", ErrnoText()));

    png_image png;
    std::memset(&png, 0, sizeof png);
    png.version = PNG_IMAGE_VERSION;
    png.width = static_cast<png_uint_32>(image.width);
    png.height = static_cast<png_uint_32>(image.height);
    png.format = PNG_FORMAT_RGBA;
    PngImageGuard guard{&png};
    const bool ok = png_image_write_to_stdio(&png, file.get(), /*convert_to_8_bit=*/0,
                                             image.rgba.data(), /*row_stride=*/0,
                                             /*colormap=*/nullptr) != 0;
    // fclose flushes: a full disk shows up here, not in libpng.
    const bool closed = std::fclose(file.release()) == 0;
    if (!ok || !closed) {
      const std::string why = !ok ? std::string("libpng: ") + png.message : ErrnoText();
      std::remove(tmp.c_str());
      ThrowFileError(name, fmt::format("cannot write PNG: {}", why));
    }
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) {
    std::remove(tmp.c_str());
    ThrowFileError(name, fmt::format("cannot move {} into place: {}", tmp.string(), ec.message()));
  }
}

Image ReadPng(const std::filesystem::path& path) {
  const std::string name = path.string();
  png_image png;
  std::memset(&png, 0, sizeof png);
  png.version = PNG_IMAGE_VERSION;
  PngImageGuard guard{&png};
  if (png_image_begin_read_from_file(&png, name.c_str()) == 0) {
    ThrowFileError(name, fmt::format("cannot read PNG: {}", png.message));
  }
  png.format = PNG_FORMAT_RGBA;
  Image image;
  image.width = static_cast<int>(png.width);
  image.height = static_cast<int>(png.height);
  image.rgba.resize(PNG_IMAGE_SIZE(png));
  if (png_image_finish_read(&png, /*background=*/nullptr, image.rgba.data(), /*row_stride=*/0,
                            /*colormap=*/nullptr) == 0) {
    ThrowFileError(name, fmt::format("cannot decode PNG: {}", png.message));
  }
  return image;
}

double NonBackgroundFraction(const Image& image) {
  const size_t n = image.rgba.size() / 4;
  if (n == 0) return 0.0;
  size_t count = 0;
  for (size_t i = 0; i < n; ++i) {
    const uint8_t* p = image.rgba.data() + 4 * i;
    if (!IsBackground(p[0], p[1], p[2])) ++count;
  }
  return static_cast<double>(count) / static_cast<double>(n);
}

int64_t CountCutFacePixels(const Image& image) {
  const size_t n = image.rgba.size() / 4;
  int64_t count = 0;
  for (size_t i = 0; i < n; ++i) {
    const uint8_t* p = image.rgba.data() + 4 * i;
    if (IsCutFaceColour(p[0], p[1], p[2])) ++count;
  }
  return count;
}

double MeanAbsoluteDifference(const Image& a, const Image& b) {
  if (a.width != b.width || a.height != b.height || a.rgba.size() != b.rgba.size()) {
    throw std::invalid_argument(fmt::format("MeanAbsoluteDifference: {}x{} vs {}x{} images",
                                            a.width, a.height, b.width, b.height));
  }
  const size_t n = a.rgba.size() / 4;
  if (n == 0) return 0.0;
  uint64_t sum = 0;
  for (size_t i = 0; i < n; ++i) {
    for (size_t c = 0; c < 3; ++c) {
      sum += static_cast<uint64_t>(std::abs(int{a.rgba[4 * i + c]} - int{b.rgba[4 * i + c]}));
    }
  }
  return static_cast<double>(sum) / static_cast<double>(3 * n);
}

}  // namespace cutsim::render
