// The check a .msh file passes before libgmsh reads it (msh_check.h): the
// file is read as gmsh reads it (section lines, then whitespace-separated
// tokens in ASCII or fixed-size little-endian values in binary) and every
// count, tag and node reference is checked.
#include "common/mesh/msh_check.h"

#include <algorithm>
#include <array>
#include <bit>
#include <charconv>
#include <cstdint>
#include <cstring>
#include <optional>
#include <string_view>
#include <unordered_set>

#include <fmt/format.h>

#include "common/core/error.h"
#include "common/core/finite.h"
#include "common/core/input_file.h"
#include "common/mesh/mesh_validation.h"

namespace cutsim::mesh::internal {
namespace {

static_assert(std::endian::native == std::endian::little, "binary .msh checks assume a little-endian host");

/// Dimension and node count of gmsh element types 1–19.
struct ElementKind {
  int dim = 0;
  int nodes = 0;
};

std::optional<ElementKind> GmshElementKind(int64_t type) {
  static constexpr std::array<ElementKind, 20> kKinds{{{-1, 0},  {1, 2},  {2, 3},  {2, 4},  {3, 4},
                                                       {3, 8},   {3, 6},  {3, 5},  {1, 3},  {2, 6},
                                                       {2, 9},   {3, 10}, {3, 27}, {3, 18}, {3, 14},
                                                       {0, 1},   {2, 8},  {3, 20}, {3, 15}, {3, 13}}};
  if (type < 1 || type >= static_cast<int64_t>(kKinds.size())) return std::nullopt;
  return kKinds[static_cast<size_t>(type)];
}

/// The file's bytes and a read position. Errors name the line of the last
/// token (ASCII) or the byte offset (binary).
class MshCursor {
 public:
  MshCursor(const std::string& path, const std::string& bytes) : path_(path), bytes_(bytes) {}

  void set_binary(bool binary) { binary_ = binary; }
  [[nodiscard]] bool binary() const { return binary_; }
  [[nodiscard]] uint64_t left() const { return bytes_.size() - pos_; }

  [[nodiscard]] SourceRef Where() const {
    if (binary_) return {.file = path_, .field = fmt::format("byte {}", mark_)};
    const auto begin = bytes_.begin();
    return {.file = path_, .line = 1 + std::count(begin, begin + static_cast<std::ptrdiff_t>(mark_), '\n')};
  }
  [[noreturn]] void Fail(std::string_view message) const { ThrowInputError(Where(), message); }

  /// Throws unless `count` items of at least `min_bytes_each` fit in the rest.
  void Fits(int64_t count, int64_t min_bytes_each, std::string_view what) const {
    RequireCountFits(count, min_bytes_each, left(), Where(), what);
  }

  /// The next line without its line end; false at the end of the file.
  bool NextLine(std::string& line) {
    if (pos_ >= bytes_.size()) return false;
    mark_ = pos_;
    const size_t end = bytes_.find('\n', pos_);
    const size_t stop = end == std::string::npos ? bytes_.size() : end;
    line.assign(bytes_, pos_, stop - pos_);
    while (!line.empty() && (line.back() == '\r' || line.back() == ' ' || line.back() == '\t')) line.pop_back();
    pos_ = end == std::string::npos ? bytes_.size() : end + 1;
    return true;
  }

  /// The next whitespace-separated token (ASCII).
  std::string_view Token(std::string_view what) {
    while (pos_ < bytes_.size() && std::strchr(" \t\r\n\f\v", bytes_[pos_]) != nullptr && bytes_[pos_] != '\0') {
      ++pos_;
    }
    mark_ = pos_;
    if (pos_ >= bytes_.size()) Fail(fmt::format("unexpected end of file reading {}", what));
    const size_t start = pos_;
    while (pos_ < bytes_.size() && std::strchr(" \t\r\n\f\v", bytes_[pos_]) == nullptr) ++pos_;
    return std::string_view(bytes_).substr(start, pos_ - start);
  }

  int64_t TokenInt(std::string_view what) {
    const std::string_view tok = Token(what);
    int64_t v = 0;
    const auto [end, ec] = std::from_chars(tok.data(), tok.data() + tok.size(), v);
    if (ec != std::errc() || end != tok.data() + tok.size()) Fail(fmt::format("bad {} '{}'", what, tok));
    return v;
  }

  double TokenReal(std::string_view what) {
    const std::string_view tok = Token(what);
    double v = 0;
    const auto [end, ec] = std::from_chars(tok.data(), tok.data() + tok.size(), v);
    if (ec != std::errc() || end != tok.data() + tok.size()) Fail(fmt::format("bad {} '{}'", what, tok));
    return v;
  }

  /// A little-endian value of type T (binary).
  template <typename T>
  T Raw(std::string_view what) {
    mark_ = pos_;
    if (left() < sizeof(T)) Fail(fmt::format("the file ends inside {}", what));
    T v;
    std::memcpy(&v, bytes_.data() + pos_, sizeof(T));
    pos_ += sizeof(T);
    return v;
  }

 private:
  const std::string& path_;
  const std::string& bytes_;
  size_t pos_ = 0;
  size_t mark_ = 0;  // start of the last line, token or value
  bool binary_ = false;
};

/// Values as the file's format stores them: gmsh's `int` (binary: 4 bytes),
/// `size_t` (binary: 8 bytes) and reals (binary: 8 bytes, the only data
/// size accepted). Reals must be finite.
int64_t ReadInt(MshCursor& c, std::string_view what) {
  return c.binary() ? int64_t{c.Raw<int32_t>(what)} : c.TokenInt(what);
}
int64_t ReadSize(MshCursor& c, std::string_view what) {
  if (!c.binary()) {
    const int64_t v = c.TokenInt(what);
    if (v < 0) c.Fail(fmt::format("{} {} is negative", what, v));
    return v;
  }
  const uint64_t v = c.Raw<uint64_t>(what);
  if (v > static_cast<uint64_t>(INT64_MAX)) c.Fail(fmt::format("{} {} is out of range", what, v));
  return static_cast<int64_t>(v);
}
double ReadReal(MshCursor& c, std::string_view what) {
  const double v = c.binary() ? c.Raw<double>(what) : c.TokenReal(what);
  RequireFinite(v, c.Where(), what);
  return v;
}
/// Smallest bytes an int, size or real takes (ASCII: a digit and a space).
int64_t IntBytes(const MshCursor& c) { return c.binary() ? 4 : 2; }
int64_t SizeBytes(const MshCursor& c) { return c.binary() ? 8 : 2; }
int64_t RealBytes(const MshCursor& c) { return c.binary() ? 8 : 2; }

/// The file's state as the sections go by.
struct MshState {
  bool v41 = false;
  bool have_entities = false;
  bool have_nodes = false;
  std::array<std::unordered_set<int64_t>, 4> entities;  // 4.1: tags per dimension
  std::unordered_set<int64_t> nodes;
};

/// Lines up to and including `end` (blank lines allowed before it).
void ExpectEnd(MshCursor& c, std::string_view end) {
  std::string line;
  while (c.NextLine(line)) {
    if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
    if (line != end) c.Fail(fmt::format("expected {} (a count does not match the data), got '{}'", end, line.substr(0, 40)));
    return;
  }
  c.Fail(fmt::format("unexpected end of file: no {}", end));
}

void SkipSection(MshCursor& c, std::string_view end) {
  std::string line;
  while (c.NextLine(line)) {
    if (line == end) return;
  }
  c.Fail(fmt::format("unexpected end of file: no {}", end));
}

/// A count given on its own ASCII line (2.2 binary sections) or as a token.
int64_t ReadCount22(MshCursor& c, std::string_view what) {
  if (!c.binary()) return c.TokenInt(what);
  std::string line;
  if (!c.NextLine(line)) c.Fail(fmt::format("unexpected end of file reading {}", what));
  int64_t v = 0;
  const auto [end, ec] = std::from_chars(line.data(), line.data() + line.size(), v);
  if (ec != std::errc() || end != line.data() + line.size()) c.Fail(fmt::format("bad {} '{}'", what, line));
  return v;
}

void AddNode(MshCursor& c, MshState& s, int64_t tag) {
  if (!s.nodes.insert(tag).second) c.Fail(fmt::format("node {} defined twice", tag));
}

void RequireNode(MshCursor& c, const MshState& s, int64_t element, int64_t node) {
  if (!s.nodes.contains(node)) {
    c.Fail(fmt::format("element {} names node {}, which $Nodes does not define", element, node));
  }
}

ElementKind KindOf(MshCursor& c, int64_t type) {
  const std::optional<ElementKind> kind = GmshElementKind(type);
  if (!kind) {
    c.Fail(fmt::format("element type {} is not read: cutsim checks gmsh element types 1-19 (points, lines, "
                       "triangles, quadrangles, tetrahedra, hexahedra, prisms, pyramids up to second order)",
                       type));
  }
  return *kind;
}

// ---- version 2.2 ------------------------------------------------------------

void Nodes22(MshCursor& c, MshState& s) {
  const int64_t n = ReadCount22(c, "node count");
  if (n > kMaxMeshNodes) c.Fail(fmt::format("{} nodes exceed the limit {}", n, kMaxMeshNodes));
  c.Fits(n, c.binary() ? 4 + 3 * 8 : 8, "node count");
  s.nodes.reserve(static_cast<size_t>(n));
  for (int64_t i = 0; i < n; ++i) {
    const int64_t tag = ReadInt(c, "node id");
    for (int k = 0; k < 3; ++k) (void)ReadReal(c, "node coordinate");
    AddNode(c, s, tag);
  }
}

void Elements22(MshCursor& c, MshState& s) {
  const int64_t n = ReadCount22(c, "element count");
  c.Fits(n, c.binary() ? 16 : 10, "element count");
  if (!c.binary()) {
    for (int64_t i = 0; i < n; ++i) {
      const int64_t id = c.TokenInt("element id");
      const ElementKind kind = KindOf(c, c.TokenInt("element type"));
      const int64_t tags = c.TokenInt("tag count");
      c.Fits(tags, 2, "tag count");
      for (int64_t t = 0; t < tags; ++t) (void)c.TokenInt("element tag");
      for (int k = 0; k < kind.nodes; ++k) RequireNode(c, s, id, c.TokenInt("element node"));
    }
    return;
  }
  // Binary: blocks of elements of one type and tag count.
  for (int64_t done = 0; done < n;) {
    const ElementKind kind = KindOf(c, c.Raw<int32_t>("element type"));
    const int64_t count = c.Raw<int32_t>("element count of a block");
    const int64_t tags = c.Raw<int32_t>("tag count");
    if (count < 1 || count > n - done) c.Fail(fmt::format("block of {} elements, {} remain", count, n - done));
    if (tags < 0) c.Fail(fmt::format("tag count {} is negative", tags));
    c.Fits(count, 4 * (1 + tags + kind.nodes), "element count of a block");
    for (int64_t i = 0; i < count; ++i) {
      const int64_t id = c.Raw<int32_t>("element id");
      for (int64_t t = 0; t < tags; ++t) (void)c.Raw<int32_t>("element tag");
      for (int k = 0; k < kind.nodes; ++k) RequireNode(c, s, id, c.Raw<int32_t>("element node"));
    }
    done += count;
  }
}

// ---- version 4.1 ------------------------------------------------------------

void Entities41(MshCursor& c, MshState& s) {
  std::array<int64_t, 4> counts{};
  for (int64_t& n : counts) n = ReadSize(c, "entity count");
  for (int dim = 0; dim < 4; ++dim) {
    c.Fits(counts[dim], IntBytes(c) + 4 * RealBytes(c) + SizeBytes(c), "entity count");
    for (int64_t i = 0; i < counts[dim]; ++i) {
      const int64_t tag = ReadInt(c, "entity tag");
      if (tag < 1) c.Fail(fmt::format("entity tag {} is not positive", tag));
      if (!s.entities[dim].insert(tag).second) c.Fail(fmt::format("entity ({}, {}) defined twice", dim, tag));
      for (int k = 0; k < (dim == 0 ? 3 : 6); ++k) (void)ReadReal(c, "entity bounding box");
      const int64_t physicals = ReadSize(c, "physical tag count");
      c.Fits(physicals, IntBytes(c), "physical tag count");
      for (int64_t k = 0; k < physicals; ++k) (void)ReadInt(c, "physical tag");
      if (dim == 0) continue;
      const int64_t bounds = ReadSize(c, "bounding entity count");
      c.Fits(bounds, IntBytes(c), "bounding entity count");
      for (int64_t k = 0; k < bounds; ++k) {
        const int64_t b = ReadInt(c, "bounding entity tag");
        if (!s.entities[dim - 1].contains(b < 0 ? -b : b)) {
          c.Fail(fmt::format("entity ({}, {}) is bounded by ({}, {}), which $Entities does not define", dim, tag,
                             dim - 1, b));
        }
      }
    }
  }
  s.have_entities = true;
}

/// A block header's entity (dimension 0–3, defined in $Entities).
int RequireEntity(MshCursor& c, const MshState& s, int64_t dim, int64_t tag) {
  if (dim < 0 || dim > 3) c.Fail(fmt::format("entity dimension {} outside 0..3", dim));
  if (!s.entities[static_cast<size_t>(dim)].contains(tag)) {
    c.Fail(fmt::format("entity ({}, {}) is not defined in $Entities", dim, tag));
  }
  return static_cast<int>(dim);
}

void Nodes41(MshCursor& c, MshState& s) {
  const int64_t blocks = ReadSize(c, "node block count");
  const int64_t n = ReadSize(c, "node count");
  const int64_t min_tag = ReadSize(c, "smallest node tag");
  const int64_t max_tag = ReadSize(c, "largest node tag");
  if (n > kMaxMeshNodes) c.Fail(fmt::format("{} nodes exceed the limit {}", n, kMaxMeshNodes));
  c.Fits(blocks, 3 * IntBytes(c) + SizeBytes(c), "node block count");
  c.Fits(n, SizeBytes(c) + 3 * RealBytes(c), "node count");
  s.nodes.reserve(static_cast<size_t>(n));
  int64_t total = 0;
  for (int64_t b = 0; b < blocks; ++b) {
    const int64_t dim_raw = ReadInt(c, "node block dimension");
    const int dim = RequireEntity(c, s, dim_raw, ReadInt(c, "node block entity"));
    const int64_t parametric = ReadInt(c, "node block parametric flag");
    if (parametric != 0 && parametric != 1) c.Fail(fmt::format("parametric flag {} is not 0 or 1", parametric));
    const int64_t count = ReadSize(c, "node count of a block");
    if (count > n - total) c.Fail(fmt::format("block of {} nodes, the header leaves {}", count, n - total));
    for (int64_t i = 0; i < count; ++i) {
      const int64_t tag = ReadSize(c, "node tag");
      if (tag < 1 || tag < min_tag || tag > max_tag) {
        c.Fail(fmt::format("node tag {} outside the header's range {}..{} (tags start at 1)", tag, min_tag, max_tag));
      }
      AddNode(c, s, tag);
    }
    const int64_t values = count * (3 + (parametric != 0 ? dim : 0));
    for (int64_t i = 0; i < values; ++i) (void)ReadReal(c, "node coordinate");
    total += count;
  }
  if (total != n) c.Fail(fmt::format("the blocks hold {} nodes, the header says {}", total, n));
}

void Elements41(MshCursor& c, MshState& s) {
  const int64_t blocks = ReadSize(c, "element block count");
  const int64_t n = ReadSize(c, "element count");
  const int64_t min_tag = ReadSize(c, "smallest element tag");
  const int64_t max_tag = ReadSize(c, "largest element tag");
  c.Fits(blocks, 3 * IntBytes(c) + SizeBytes(c), "element block count");
  c.Fits(n, 2 * SizeBytes(c), "element count");
  int64_t total = 0;
  for (int64_t b = 0; b < blocks; ++b) {
    const int64_t dim_raw = ReadInt(c, "element block dimension");
    const int dim = RequireEntity(c, s, dim_raw, ReadInt(c, "element block entity"));
    const ElementKind kind = KindOf(c, ReadInt(c, "element type"));
    if (kind.dim != dim) c.Fail(fmt::format("elements of dimension {} in a block of dimension {}", kind.dim, dim));
    const int64_t count = ReadSize(c, "element count of a block");
    if (count > n - total) c.Fail(fmt::format("block of {} elements, the header leaves {}", count, n - total));
    c.Fits(count, (1 + kind.nodes) * SizeBytes(c), "element count of a block");
    for (int64_t i = 0; i < count; ++i) {
      const int64_t tag = ReadSize(c, "element tag");
      if (tag < 1 || tag < min_tag || tag > max_tag) {
        c.Fail(fmt::format("element tag {} outside the header's range {}..{}", tag, min_tag, max_tag));
      }
      for (int k = 0; k < kind.nodes; ++k) RequireNode(c, s, tag, ReadSize(c, "element node"));
    }
    total += count;
  }
  if (total != n) c.Fail(fmt::format("the blocks hold {} elements, the header says {}", total, n));
}

/// $MeshFormat: version 2.2 or 4.1, ASCII or little-endian binary, 8-byte
/// reals. Sets the cursor's mode and returns whether it is 4.1.
bool MeshFormat(MshCursor& c) {
  std::string line;
  while (c.NextLine(line) && line.empty()) {
  }
  if (line != "$MeshFormat") {
    c.Fail("not a .msh file cutsim reads: it must start with $MeshFormat (versions 2.2 and 4.1)");
  }
  const std::string_view version = c.Token("the format version");
  const std::string_view type = c.Token("the file type");
  const std::string_view size = c.Token("the data size");
  if (version != "2.2" && version != "4.1") {
    c.Fail(fmt::format("version {}: cutsim reads .msh 2.2 and 4.1 (`gmsh FILE -save -format msh41` converts)",
                       version));
  }
  if (type != "0" && type != "1") c.Fail(fmt::format("file type '{}' is neither 0 (ASCII) nor 1 (binary)", type));
  if (size != "8") c.Fail(fmt::format("data size '{}': only 8-byte reals are read", size));
  (void)c.NextLine(line);  // the rest of the format line
  if (type == "1") {
    c.set_binary(true);
    const int32_t one = c.Raw<int32_t>("the binary format's integer 1");
    if (one != 1) {
      c.Fail(one == 0x01000000 ? "a big-endian binary .msh is not read (write it on this machine's byte order)"
                               : "binary .msh without the integer 1 after its format line");
    }
  }
  ExpectEnd(c, "$EndMeshFormat");
  return version == "4.1";
}

}  // namespace

void CheckMshBeforeGmsh(const std::string& path, const std::string& bytes) {
  MshCursor c(path, bytes);
  MshState s;
  s.v41 = MeshFormat(c);
  std::string line;
  while (c.NextLine(line)) {
    if (line.empty()) continue;
    if (line == "$PhysicalNames") {
      SkipSection(c, "$EndPhysicalNames");  // ASCII names, even in binary files; no node is named
    } else if (line == "$Entities" && s.v41 && !s.have_entities) {
      Entities41(c, s);
      ExpectEnd(c, "$EndEntities");
    } else if (line == "$Nodes" && !s.have_nodes) {
      if (s.v41 && !s.have_entities) c.Fail("$Nodes before $Entities");
      if (s.v41) {
        Nodes41(c, s);
      } else {
        Nodes22(c, s);
      }
      s.have_nodes = true;
      ExpectEnd(c, "$EndNodes");
    } else if (line == "$Elements") {
      if (!s.have_nodes) c.Fail("$Elements before $Nodes");
      if (s.v41) {
        Elements41(c, s);
      } else {
        Elements22(c, s);
      }
      ExpectEnd(c, "$EndElements");
    } else {
      c.Fail(fmt::format("'{}': cutsim reads only the sections $MeshFormat, $PhysicalNames, {}$Nodes and "
                         "$Elements, once each",
                         line.substr(0, 40), s.v41 ? "$Entities, " : ""));
    }
  }
}

}  // namespace cutsim::mesh::internal
