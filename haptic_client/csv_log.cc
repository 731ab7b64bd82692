#include "haptic_client/csv_log.h"

#include <pthread.h>

#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>

#include <fmt/format.h>

#include "common/core/input_file.h"
#include "common/core/error.h"
#include "common/core/log.h"

namespace cutsim::haptic_client {

CsvWriter::CsvWriter(std::string path, CsvRing& ring) : path_(std::move(path)), ring_(ring) {
  const std::filesystem::path p(path_);
  if (p.has_parent_path()) std::filesystem::create_directories(p.parent_path());
  CheckOutputPath(path_, "haptic log (--csv)");  // Finish renames over it: never over a device or a pipe
  tmp_ = path_ + ".tmp";
  file_ = std::fopen(tmp_.c_str(), "w");
  if (file_ == nullptr) ThrowFileError(path_, fmt::format("cannot write the CSV: {}", std::strerror(errno)));
  std::fputs("t_s,x_m,y_m,z_m,fx_n,fy_n,fz_n,f_n,model_age_ms,period_us,lateness_us,watchdog_gain,"
             "phase,cuts,contact,energy_j,dissipated_j,model_seq,epoch\n",
             file_);
  thread_ = std::thread([this] {
    pthread_setname_np(pthread_self(), "cutsim-csv");
    while (!stop_.load()) {
      Flush();
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    Flush();
  });
}

uint64_t CsvWriter::Finish() {
  if (thread_.joinable()) {
    stop_.store(true);
    thread_.join();
  }
  if (file_ != nullptr) {
    const bool ok = std::fflush(file_) == 0 && !std::ferror(file_);
    std::fclose(file_);
    file_ = nullptr;
    std::error_code ec;
    if (ok) std::filesystem::rename(tmp_, path_, ec);
    if (!ok || ec) Log().error("could not complete the CSV {} (left {} in place)", path_, tmp_);
  }
  return rows_;
}

void CsvWriter::Flush() {
  rows_ += ring_.Drain([&](const CsvRow& r) {
    const double f = std::sqrt(r.fx * r.fx + r.fy * r.fy + r.fz * r.fz);
    std::fprintf(file_, "%.6f,%.7g,%.7g,%.7g,%.6g,%.6g,%.6g,%.6g,%.4f,%.2f,%.2f,%.5f,%d,%llu,%d,%.6g,%.6g,%llu,%llu\n",
                 r.t, r.x, r.y, r.z, r.fx, r.fy, r.fz, f, r.model_age_ms, r.period_us, r.lateness_us,
                 r.watchdog_gain, r.phase, static_cast<unsigned long long>(r.cuts), r.contact, r.energy_j,
                 r.dissipated_j, static_cast<unsigned long long>(r.model_seq),
                 static_cast<unsigned long long>(r.epoch));
  });
}

}  // namespace cutsim::haptic_client
