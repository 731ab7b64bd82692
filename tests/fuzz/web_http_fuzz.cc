// The browser servers' HTTP requests as the shared core reads them
// (common/web/web_core.h): the bytes parsed with the core's limits, then
// every check a request passes (Host, token, Origin, path, WebSocket key),
// against a loopback, a LAN and a wildcard server.
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>

#include <boost/beast/http.hpp>

#include "common/web/web_core.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace cutsim::web;
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  boost::beast::http::request<boost::beast::http::empty_body> req;
  if (!ParseRequest(bytes, 8192, &req)) return 0;
  static const ServedHosts kHosts[] = {{"127.0.0.1", 8090, {"station.lab"}},
                                       {"192.168.1.5", 80, {}},
                                       {"::", 8090, {}}};
  for (const ServedHosts& h : kHosts) {
    (void)CheckRequest(req, h, "0123456789abcdef0123", "/ws");
    (void)CheckRequest(req, h, "", "/ws");
    (void)h.AllowsOrigin(bytes);
  }
  (void)IsValidWebSocketKey(bytes);
  return 0;
}
