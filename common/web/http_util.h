#pragma once
/// @file
/// What the observer and the trainee servers share about serving a page:
/// the page's files read into memory, the path and token of a request
/// target, and a constant-time comparison of secrets.

#include <filesystem>
#include <memory>
#include <optional>
#include <map>
#include <string>
#include <string_view>
#include <utility>

#include <boost/beast/http.hpp>

namespace cutsim::web {

/// A page file held in memory, with its Content-Type.
struct PageFile {
  std::string body;
  std::string content_type;
};

/// Reads each URL path's file (`files`: URL path → file). Throws a file
/// error naming the file and `what` (e.g. "the observer page's files").
[[nodiscard]] std::map<std::string, PageFile> ReadPageFiles(const std::map<std::string, std::filesystem::path>& files,
                                                            const std::string& what);

/// The path of a request target, and the value of its `token` parameter.
[[nodiscard]] std::pair<std::string, std::string> SplitTarget(std::string_view target);

/// The raw value of query parameter `name` in a request target, or nullopt
/// when the target has none (the first occurrence counts).
[[nodiscard]] std::optional<std::string> QueryParam(std::string_view target, std::string_view name);

/// A response to `req`: `body` as `type`, never cached, kept alive only when
/// the request asks and the status is 200. Shared, to outlive its async write.
[[nodiscard]] std::shared_ptr<boost::beast::http::response<boost::beast::http::string_body>> MakeReply(
    const boost::beast::http::request<boost::beast::http::empty_body>& req, boost::beast::http::status status,
    const std::string& body, const std::string& type);

/// Comparison whose time does not depend on where the strings differ.
[[nodiscard]] bool SameSecret(const std::string& a, const std::string& b);

}  // namespace cutsim::web
