#pragma once
/// @file
/// Blocking HTTP and WebSocket clients on loopback for the tests of the web
/// servers (tests/unit/web, tests/unit/devices) and bench/lab_bench. They
/// are compiled once, in cutsim_web_test_client, and their header names no
/// Boost type, so a test that uses them does not instantiate Beast's client
/// templates itself.

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <utility>

namespace cutsim::test {

/// A WebSocket client of a server on 127.0.0.1, on an I/O context of its
/// own; every call blocks until it is done.
class WebSocketClient {
 public:
  WebSocketClient();
  ~WebSocketClient();
  WebSocketClient(const WebSocketClient&) = delete;
  WebSocketClient& operator=(const WebSocketClient&) = delete;

  /// Connects to `port` and asks for the upgrade at `target`, sending an
  /// `Origin` header when `origin` is not empty. False when the upgrade is
  /// refused; throws when the connection is.
  bool Open(uint16_t port, const std::string& target = "/ws", const std::string& origin = "");

  /// The next message and whether it is binary; nullopt when the connection
  /// ends (or a read fails).
  [[nodiscard]] std::optional<std::pair<std::string, bool>> Read();

  /// The bytes of the next message, text or binary; nullopt as for Read().
  [[nodiscard]] std::optional<std::string> ReadData();

  /// Sends one message, binary or text. False when the write fails (the
  /// server may close the connection midway).
  bool Write(std::string_view bytes, bool binary = false);

  /// The close frame the server sent, as (code, reason); code 0 when none
  /// arrived yet.
  [[nodiscard]] std::pair<int, std::string> CloseReason() const;

  /// Sends a WebSocket close frame (code 1000, normal closure) and waits for
  /// the server's; false when the close handshake fails.
  bool Close();

  /// Shuts the TCP connection down in both directions, which wakes a Read()
  /// blocked on another thread.
  void Shutdown();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// GET `target` from the server on 127.0.0.1:`port` (HTTP/1.1, `Host` set
/// to the address and port): the response's status code and body.
[[nodiscard]] std::pair<int, std::string> HttpGet(uint16_t port, const std::string& target);

}  // namespace cutsim::test
