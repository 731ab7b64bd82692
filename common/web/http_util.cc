#include "common/web/http_util.h"

#include <fstream>
#include <sstream>

#include <fmt/format.h>

#include "common/core/error.h"

namespace cutsim::web {
namespace {

std::string ContentType(const std::filesystem::path& path) {
  const std::string ext = path.extension().string();
  if (ext == ".html") return "text/html; charset=utf-8";
  if (ext == ".js" || ext == ".mjs") return "text/javascript; charset=utf-8";
  if (ext == ".css") return "text/css; charset=utf-8";
  return "application/octet-stream";
}

}  // namespace

std::map<std::string, PageFile> ReadPageFiles(const std::map<std::string, std::filesystem::path>& files,
                                              const std::string& what) {
  std::map<std::string, PageFile> out;
  for (const auto& [path, file] : files) {
    std::ifstream in(file, std::ios::binary);
    if (!in) ThrowFileError(file.string(), fmt::format("cannot open ({})", what));
    std::ostringstream text;
    text << in.rdbuf();
    out[path] = {text.str(), ContentType(file)};
  }
  return out;
}

std::pair<std::string, std::string> SplitTarget(std::string_view target) {
  const size_t q = target.find('?');
  std::string path(target.substr(0, q));
  std::string token;
  if (q != std::string_view::npos) {
    std::string_view query = target.substr(q + 1);
    while (!query.empty()) {
      const size_t amp = query.find('&');
      const std::string_view param = query.substr(0, amp);
      if (param.substr(0, 6) == "token=") token = std::string(param.substr(6));
      if (amp == std::string_view::npos) break;
      query.remove_prefix(amp + 1);
    }
  }
  return {path, token};
}

std::optional<std::string> QueryParam(std::string_view target, std::string_view name) {
  const size_t q = target.find('?');
  if (q == std::string_view::npos) return std::nullopt;
  std::string_view query = target.substr(q + 1);
  while (!query.empty()) {
    const size_t amp = query.find('&');
    const std::string_view param = query.substr(0, amp);
    if (param.size() > name.size() && param.substr(0, name.size()) == name && param[name.size()] == '=') {
      return std::string(param.substr(name.size() + 1));
    }
    if (amp == std::string_view::npos) break;
    query.remove_prefix(amp + 1);
  }
  return std::nullopt;
}

std::shared_ptr<boost::beast::http::response<boost::beast::http::string_body>> MakeReply(
    const boost::beast::http::request<boost::beast::http::empty_body>& req, boost::beast::http::status status,
    const std::string& body, const std::string& type) {
  namespace http = boost::beast::http;
  auto res = std::make_shared<http::response<http::string_body>>(status, req.version());
  res->set(http::field::content_type, type);
  res->set(http::field::cache_control, "no-store");
  res->keep_alive(req.keep_alive() && status == http::status::ok);
  res->body() = body;
  res->prepare_payload();
  return res;
}

bool SameSecret(const std::string& a, const std::string& b) {
  if (a.size() != b.size()) return false;
  unsigned diff = 0;
  for (size_t i = 0; i < a.size(); ++i) diff |= static_cast<unsigned>(a[i] ^ b[i]);
  return diff == 0;
}

}  // namespace cutsim::web
