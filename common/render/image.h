#pragma once
/// @file
/// An RGBA8 image with top-down rows, PNG input/output, and the pixel metrics
/// the tests (and the viewer's self-checks) use to judge a rendered frame.

#include <cstdint>
#include <filesystem>
#include <vector>

namespace cutsim::render {

/// An 8-bit RGBA image, rows stored top-down (row 0 is the top of the picture).
struct Image {
  int width = 0;              ///< Columns, pixels.
  int height = 0;             ///< Rows, pixels.
  std::vector<uint8_t> rgba;  ///< width·height·4 bytes, R G B A per pixel, top-down rows.

  /// The four bytes of pixel (x, y), y counted from the top. No bounds check.
  [[nodiscard]] const uint8_t* pixel(int x, int y) const {
    return rgba.data() +
           (static_cast<size_t>(y) * static_cast<size_t>(width) + static_cast<size_t>(x)) * 4;
  }
  /// True when width, height > 0 and rgba has exactly width·height·4 bytes.
  [[nodiscard]] bool valid() const;
};

/// Writes `image` as an 8-bit RGBA PNG. The data goes to `path` + ".tmp" first
/// and is renamed over `path` only when complete, so a failed or interrupted
/// write never replaces a good file. Throws `InputError` naming `path` when
/// the image is invalid or the file cannot be written.
void WritePng(const std::filesystem::path& path, const Image& image);

/// Reads any PNG and converts it to 8-bit RGBA. Throws `InputError` naming
/// `path` when it cannot be read or decoded.
[[nodiscard]] Image ReadPng(const std::filesystem::path& path);

/// Fraction of pixels in [0, 1] that are not the background colour (see
/// `IsBackground` in palette.h): how much of the frame the scene covers.
[[nodiscard]] double NonBackgroundFraction(const Image& image);

/// Number of pixels classified as a face opened by a cut (`IsCutFaceColour`).
[[nodiscard]] int64_t CountCutFacePixels(const Image& image);

/// Mean absolute difference of the R, G, B channels (alpha ignored), in
/// [0, 255]. Throws `std::invalid_argument` when the sizes differ.
[[nodiscard]] double MeanAbsoluteDifference(const Image& a, const Image& b);

}  // namespace cutsim::render
