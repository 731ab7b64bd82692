// The HTTP/WebSocket core both browser servers share: the hosts a server
// serves (Host and Origin, DNS rebinding), RFC 6455 keys, and, run once for
// the observer server and once for the trainee server, every refusal the
// core makes on real loopback sockets: token, Origin, Host, key, path, the
// client cap taken at the upgrade, and the connection caps at accept. Then
// the core alone: accept backs off when the process runs out of descriptors.
#include <gtest/gtest.h>

#include <signal.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <netinet/in.h>
#include <arpa/inet.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include <boost/asio/ip/tcp.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>

#include "common/core/error.h"
#include "common/web/observer_server.h"
#include "common/web/trainee_server.h"
#include "common/web/web_core.h"
#include "tests/support/web_test_util.h"

namespace cutsim::web {
namespace {

using test::Eventually;
using test::TempPage;

namespace net = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
using tcp = net::ip::tcp;
using namespace std::chrono_literals;

constexpr const char* kToken = "0123456789abcdef0123";
constexpr const char* kKey = "dGhlIHNhbXBsZSBub25jZQ==";  // RFC 6455's example

TEST(ServedHostsTest, ALoopbackServerServesItsAddressLocalhostAndConfiguredNames) {
  const ServedHosts h{"127.0.0.1", 8090, {"station.lab"}};
  EXPECT_TRUE(h.Serves("127.0.0.1:8090"));
  EXPECT_TRUE(h.Serves("localhost:8090"));
  EXPECT_TRUE(h.Serves("LOCALHOST:8090"));
  EXPECT_TRUE(h.Serves("[::1]:8090"));
  EXPECT_TRUE(h.Serves("station.lab:8090"));
  EXPECT_FALSE(h.Serves("evil.example:8090"));  // a rebound name
  EXPECT_FALSE(h.Serves("127.0.0.1:8091"));     // another port
  EXPECT_FALSE(h.Serves("127.0.0.1"));          // port 80
  EXPECT_FALSE(h.Serves("10.0.0.1:8090"));
  EXPECT_FALSE(h.Serves(""));
  EXPECT_FALSE(h.Serves(":8090"));
  EXPECT_FALSE(h.Serves("127.0.0.1:"));
  EXPECT_FALSE(h.Serves("127.0.0.1:8090x"));
  EXPECT_FALSE(h.Serves("[::1"));
  EXPECT_TRUE(h.AllowsOrigin("http://127.0.0.1:8090"));
  EXPECT_TRUE(h.AllowsOrigin("http://localhost:8090"));
  EXPECT_FALSE(h.AllowsOrigin("http://evil.example:8090"));
  EXPECT_FALSE(h.AllowsOrigin("https://127.0.0.1:8090"));
  EXPECT_FALSE(h.AllowsOrigin("http://127.0.0.1:8090/x"));
  EXPECT_FALSE(h.AllowsOrigin("http://user@127.0.0.1:8090"));
  EXPECT_FALSE(h.AllowsOrigin("null"));
}

TEST(ServedHostsTest, AnAddressServesItselfAWildcardAnyAddress) {
  const ServedHosts lan{"192.168.1.5", 80, {}};
  EXPECT_TRUE(lan.Serves("192.168.1.5"));
  EXPECT_FALSE(lan.Serves("localhost"));
  EXPECT_FALSE(lan.Serves("127.0.0.1"));
  const ServedHosts any{"0.0.0.0", 9000, {}};
  EXPECT_TRUE(any.Serves("10.1.2.3:9000"));
  EXPECT_TRUE(any.Serves("localhost:9000"));
  EXPECT_FALSE(any.Serves("evil.example:9000"));
}

TEST(WebSocketKeyTest, AcceptsSixteenBytesOfBase64Only) {
  EXPECT_TRUE(IsValidWebSocketKey(kKey));
  EXPECT_TRUE(IsValidWebSocketKey("AAAAAAAAAAAAAAAAAAAAAA=="));
  EXPECT_FALSE(IsValidWebSocketKey("abc"));
  EXPECT_FALSE(IsValidWebSocketKey(""));
  EXPECT_FALSE(IsValidWebSocketKey("dGhlIHNhbXBsZSBub25jZQ="));    // 23 characters
  EXPECT_FALSE(IsValidWebSocketKey("dGhlIHNhbXBsZSBub25jZQ=A"));   // no padding
  EXPECT_FALSE(IsValidWebSocketKey("dGhlIHNhbXBsZSBub25jZR=="));   // bits past 16 bytes
  EXPECT_FALSE(IsValidWebSocketKey("dGhlIHNhbXBsZSBub25j*Q=="));   // not base64
}

TEST(ParseRequestTest, ParsesAHeaderAndRefusesBodiesAndOversizedHeaders) {
  http::request<http::empty_body> req;
  ASSERT_TRUE(ParseRequest("GET /ws?token=x HTTP/1.1\r\nHost: a:1\r\n\r\n", 8192, &req));
  EXPECT_EQ(std::string(req.target()), "/ws?token=x");
  EXPECT_FALSE(ParseRequest("GET / HTTP/1.1\r\nHost: a\r\n", 8192, &req));  // incomplete
  EXPECT_FALSE(ParseRequest("GET / HTTP/1.1\r\nHost: " + std::string(9000, 'a') + "\r\n\r\n", 8192, &req));
  EXPECT_FALSE(ParseRequest("POST / HTTP/1.1\r\nHost: a\r\nContent-Length: 2000\r\n\r\n", 8192, &req));
  EXPECT_FALSE(ParseRequest("\x01\x02 junk\r\n\r\n", 8192, &req));
}

// ---------------------------------------------------------------------------
// The refusals, once for each server.

struct ObserverUnderTest {
  static constexpr int kClientCap = 3;
  ObserverUnderTest(const TempPage& page, int per_peer) {
    ObserverServerOptions o;
    o.files = page.files();
    o.token = kToken;
    o.max_clients = kClientCap;
    o.max_connections_per_peer = per_peer;
    server = std::make_unique<ObserverServer>(o);
  }
  [[nodiscard]] uint16_t port() const { return server->port(); }
  [[nodiscard]] WebCoreStats web() const { return server->stats().web; }
  std::unique_ptr<ObserverServer> server;
};

struct TraineeUnderTest {
  static constexpr int kClientCap = 1;
  TraineeUnderTest(const TempPage& page, int per_peer) {
    TraineeServerOptions o;
    o.files = page.files();
    o.token = kToken;
    o.max_connections_per_peer = per_peer;
    TraineeHandlers h;
    h.on_message = [](std::string_view, int64_t) {};
    server = std::make_unique<TraineeServer>(o, h);
  }
  [[nodiscard]] uint16_t port() const { return server->port(); }
  [[nodiscard]] WebCoreStats web() const { return server->stats().web; }
  std::unique_ptr<TraineeServer> server;
};

/// A raw HTTP exchange: the request's header lines, then the status code
/// (0 when the server closed the connection without a response).
struct Raw {
  net::io_context ioc;
  tcp::socket socket{ioc};

  void Connect(uint16_t port, const std::string& from = "127.0.0.1") {
    socket.open(tcp::v4());
    socket.bind(tcp::endpoint(net::ip::make_address(from), 0));
    socket.connect(tcp::endpoint(net::ip::make_address("127.0.0.1"), port));
  }
  void Send(const std::string& target, const std::string& host, const std::string& extra, bool upgrade) {
    std::string req = "GET " + target + " HTTP/1.1\r\nHost: " + host + "\r\n" + extra;
    if (upgrade) req += "Connection: Upgrade\r\nUpgrade: websocket\r\nSec-WebSocket-Version: 13\r\n";
    req += "\r\n";
    beast::error_code ec;  // a server that closed at accept may reset the write
    net::write(socket, net::buffer(req), ec);
  }
  int Status() {
    beast::flat_buffer buffer;
    http::response_parser<http::string_body> parser;
    parser.skip(false);
    beast::error_code ec;
    http::read_header(socket, buffer, parser, ec);
    return ec ? 0 : static_cast<int>(parser.get().result_int());
  }
};

template <typename T>
class SharedCoreTest : public ::testing::Test {
 protected:
  std::string Own() const { return "127.0.0.1:" + std::to_string(server_->port()); }
  int Upgrade(const std::string& target, const std::string& host, const std::string& extra) {
    Raw r;
    r.Connect(server_->port());
    r.Send(target, host, extra, true);
    return r.Status();
  }
  int Page(const std::string& host, const std::string& from = "127.0.0.1") {
    Raw r;
    r.Connect(server_->port(), from);
    r.Send("/", host, "", false);
    return r.Status();
  }
  void StartServer(int per_peer = 64) { server_ = std::make_unique<T>(page_, per_peer); }

  TempPage page_{"core_test"};
  std::unique_ptr<T> server_;
};

using Servers = ::testing::Types<ObserverUnderTest, TraineeUnderTest>;
TYPED_TEST_SUITE(SharedCoreTest, Servers);

TYPED_TEST(SharedCoreTest, RefusesEveryBadUpgradeAndRebindingHostsAcceptsAGoodOne) {
  this->StartServer();
  const std::string own = this->Own();
  const std::string port = std::to_string(this->server_->port());
  const std::string good = "/ws?token=" + std::string(kToken);
  const std::string key = "Sec-WebSocket-Key: " + std::string(kKey) + "\r\n";
  EXPECT_EQ(this->Upgrade("/ws", own, key), 403);
  EXPECT_EQ(this->Upgrade("/ws?token=0123456789abcdef0124", own, key), 403);
  EXPECT_EQ(this->Upgrade(good, own, key + "Origin: http://evil.example\r\n"), 403);
  EXPECT_EQ(this->Upgrade(good, own, key + "Origin: http://evil.example:" + port + "\r\n"), 403);
  EXPECT_EQ(this->Upgrade(good, "evil.example:" + port, key + "Origin: http://evil.example:" + port + "\r\n"), 403);
  EXPECT_EQ(this->Page("evil.example:" + port), 403);  // a rebound page never loads
  EXPECT_EQ(this->Upgrade(good, "127.0.0.1:1", key), 403);
  EXPECT_EQ(this->Upgrade(good, own, "Sec-WebSocket-Key: abc\r\n"), 400);
  EXPECT_EQ(this->Upgrade(good, own, ""), 400);
  EXPECT_EQ(this->Upgrade("/other?token=" + std::string(kToken), own, key), 404);
  EXPECT_EQ(this->Page(own), 200);
  EXPECT_EQ(this->Page("localhost:" + port), 200);
  {
    Raw ok;
    ok.Connect(this->server_->port());
    ok.Send(good, own, key + "Origin: http://localhost:" + port + "\r\n", true);
    EXPECT_EQ(ok.Status(), 101);
  }
  const WebCoreStats s = this->server_->web();
  EXPECT_EQ(s.refused_token, 2u);
  EXPECT_EQ(s.refused_origin, 2u);
  EXPECT_EQ(s.refused_host, 3u);
  EXPECT_EQ(s.refused_key, 2u);
  EXPECT_EQ(s.bad_requests, 1u);
  EXPECT_EQ(s.pages_served, 2u);
}

TYPED_TEST(SharedCoreTest, TakesTheClientCapAtTheUpgradeEvenForSimultaneousOnes) {
  this->StartServer();
  constexpr int kTries = 12;
  std::vector<std::unique_ptr<Raw>> raws;
  const std::string extra = "Sec-WebSocket-Key: " + std::string(kKey) + "\r\n";
  for (int i = 0; i < kTries; ++i) {
    raws.push_back(std::make_unique<Raw>());
    raws.back()->Connect(this->server_->port());
  }
  // Every request is out before any handshake is answered.
  for (auto& r : raws) r->Send("/ws?token=" + std::string(kToken), this->Own(), extra, true);
  int upgraded = 0;
  for (auto& r : raws) upgraded += r->Status() == 101 ? 1 : 0;
  EXPECT_EQ(upgraded, TypeParam::kClientCap);
  EXPECT_EQ(this->server_->web().refused_cap, static_cast<uint64_t>(kTries - TypeParam::kClientCap));
  // Leaving frees the slots.
  raws.clear();
  ASSERT_TRUE(Eventually([&] { return this->server_->web().ws_clients == 0; }));
  EXPECT_EQ(this->Upgrade("/ws?token=" + std::string(kToken), this->Own(), extra), 101);
}

TYPED_TEST(SharedCoreTest, CapsIdleConnectionsPerPeerAtAcceptAndServesAnotherPeer) {
  constexpr int kPerPeer = 8;
  this->StartServer(kPerPeer);
  std::vector<std::unique_ptr<Raw>> idle;
  for (int i = 0; i < 3 * kPerPeer; ++i) {
    idle.push_back(std::make_unique<Raw>());
    idle.back()->Connect(this->server_->port());
  }
  ASSERT_TRUE(Eventually([&] {
    const WebCoreStats s = this->server_->web();
    return s.connections == kPerPeer && s.refused_connections == 2u * kPerPeer;
  }));
  EXPECT_EQ(this->Page(this->Own(), "127.0.0.1"), 0);  // this peer is at its cap: closed unanswered
  EXPECT_EQ(this->Page(this->Own(), "127.0.0.2"), 200);
  idle.clear();
  ASSERT_TRUE(Eventually([&] { return this->server_->web().connections == 0; }));
  EXPECT_EQ(this->Page(this->Own(), "127.0.0.1"), 200);
}

// ---------------------------------------------------------------------------
// The core alone: bad settings are named; out of descriptors, accept waits
// instead of spinning.

TEST(WebCoreTest, RefusesABadHostNameNamingTheFlag) {
  TempPage page("core_test");
  WebCoreOptions o;
  o.files = page.files();
  o.host_names = {"station.lab", "evil.example/x"};
  try {
    WebCore core(o, [](beast::tcp_stream&&, http::request<http::empty_body>&&, std::shared_ptr<void>) {});
    FAIL() << "a host name with a '/' was accepted";
  } catch (const InputError& e) {
    EXPECT_EQ(e.source().field, "--host-name");
  }
}

TEST(WebCoreTest, AcceptBacksOffWhenTheProcessRunsOutOfDescriptors) {
#if defined(CUTSIM_SANITIZED)
  // UBSan's vptr check reads a vtable through a pipe the first time it meets
  // an object; in a process with no descriptor left that read fails and the
  // check reports a false "invalid vptr".
  GTEST_SKIP() << "a process without descriptors cannot run under the sanitizers; the release suite runs this";
#endif
  TempPage page("core_test");
  WebCoreOptions o;
  o.files = page.files();
  o.reserved_descriptors = 0;
  o.max_connections_per_peer = 100000;
  o.accept_backoff_s = 0.1;
  WebCore core(o, [](beast::tcp_stream&&, http::request<http::empty_body>&&, std::shared_ptr<void>) {});
  core.Start();
  rlimit old{};
  ASSERT_EQ(::getrlimit(RLIMIT_NOFILE, &old), 0);
  int open_fds = 0;
  for ([[maybe_unused]] const auto& e : std::filesystem::directory_iterator("/proc/self/fd")) ++open_fds;
  int ready[2];
  ASSERT_EQ(::pipe(ready), 0);
  // Clients in a child with its own descriptors; the server's process has
  // room for a few connections only.
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    ::setrlimit(RLIMIT_NOFILE, &old);
    sockaddr_in to{};
    to.sin_family = AF_INET;
    to.sin_port = htons(core.port());
    to.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    for (int i = 0; i < 64; ++i) {
      const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
      if (fd >= 0) (void)::connect(fd, reinterpret_cast<const sockaddr*>(&to), sizeof(to));
    }
    (void)::write(ready[1], "r", 1);
    ::pause();
    ::_exit(0);
  }
  rlimit tight = old;
  tight.rlim_cur = static_cast<rlim_t>(open_fds + 8);
  ASSERT_EQ(::setrlimit(RLIMIT_NOFILE, &tight), 0);
  char c = 0;
  ASSERT_EQ(::read(ready[0], &c, 1), 1);
  std::this_thread::sleep_for(500ms);  // the flood holds the descriptors
  const WebCoreStats held = core.stats();
  ::kill(child, SIGKILL);
  ::waitpid(child, nullptr, 0);
  ASSERT_EQ(::setrlimit(RLIMIT_NOFILE, &old), 0);
  ::close(ready[0]);
  ::close(ready[1]);
  EXPECT_GE(held.accept_backoffs, 1u);
  // A spinning accept fails thousands of times in half a second; waiting
  // 0.1 s after each failure, a handful.
  EXPECT_LE(held.accept_backoffs, 50u);
  // Once the flood is gone the server serves again.
  ASSERT_TRUE(Eventually([&] { return core.stats().connections == 0; }));
  Raw r;
  r.Connect(core.port());
  r.Send("/", "127.0.0.1:" + std::to_string(core.port()), "", false);
  EXPECT_EQ(r.Status(), 200);
}

}  // namespace
}  // namespace cutsim::web
