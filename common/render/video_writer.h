#pragma once
/// @file
/// Video output by piping raw RGBA frames into an `ffmpeg` process.

#include <sys/types.h>

#include <filesystem>
#include <string>

#include "common/render/image.h"

namespace cutsim::render {

/// Encodes frames with ffmpeg (libx264 when the installed ffmpeg has it, else
/// mpeg4; yuv420p, odd sizes padded to even). The video is written to
/// "<stem>.tmp<ext>" next to `path` and renamed over `path` only when ffmpeg
/// finishes successfully, so a failed run never replaces a good video.
///
/// RAII: the destructor closes the pipe and waits for ffmpeg. If it runs
/// during exception unwinding the partial video is discarded; otherwise it
/// is committed like `Close()` (errors are logged, not thrown).
class FfmpegVideoWriter {
 public:
  /// True when an executable `ffmpeg` is on PATH.
  [[nodiscard]] static bool Available();

  /// Starts ffmpeg. The container comes from `path`'s extension (.mp4, .mkv,
  /// .avi, ...). Throws `InputError` naming `path` for a missing extension,
  /// a bad size or frame rate, or when ffmpeg cannot be started.
  FfmpegVideoWriter(std::filesystem::path path, int width, int height, double fps);
  ~FfmpegVideoWriter();

  FfmpegVideoWriter(const FfmpegVideoWriter&) = delete;
  FfmpegVideoWriter& operator=(const FfmpegVideoWriter&) = delete;
  FfmpegVideoWriter(FfmpegVideoWriter&&) = delete;
  FfmpegVideoWriter& operator=(FfmpegVideoWriter&&) = delete;

  /// Sends one frame (must be width × height). Throws `InputError` naming the
  /// file on a size mismatch or when ffmpeg has stopped reading.
  void WriteFrame(const Image& frame);

  /// Ends the stream, waits for ffmpeg and moves the video into place.
  /// Throws `InputError` naming the file when ffmpeg failed (the temporary
  /// file is removed). Idempotent.
  void Close();

  /// Frames written so far.
  [[nodiscard]] int64_t frames_written() const { return frames_written_; }
  /// The encoder in use ("libx264" or "mpeg4").
  [[nodiscard]] const std::string& codec() const { return codec_; }

 private:
  void Finish(bool commit);

  std::filesystem::path path_;      // final file
  std::filesystem::path tmp_path_;  // "<stem>.tmp<ext>" written by ffmpeg
  int width_;                       // pixels
  int height_;                      // pixels
  std::string codec_;
  int pipe_fd_ = -1;  // write end of ffmpeg's stdin
  pid_t pid_ = -1;    // ffmpeg's process id
  bool write_failed_ = false;
  int64_t frames_written_ = 0;
  int uncaught_at_start_ = 0;  // std::uncaught_exceptions() at construction
};

}  // namespace cutsim::render
