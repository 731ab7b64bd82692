#pragma once
// Private: the check every .msh file passes before libgmsh reads it.

#include <string>

namespace cutsim::mesh::internal {

/// libgmsh trusts a .msh file: an element naming a node the file never
/// defines, or a count larger than the data, crashes it or makes it
/// allocate without bound. This reads the file as gmsh will, for the
/// formats cutsim accepts (2.2 and 4.1, ASCII and little-endian binary,
/// 8-byte reals), and throws InputError naming the file and line (ASCII) or
/// byte offset (binary) unless: it starts with $MeshFormat; every count fits
/// the bytes left; node tags are unique (4.1: within the header's range)
/// and coordinates finite; 4.1 entity blocks and bounding entities name
/// entities of $Entities; element types are gmsh's 1–19 (first and second
/// order points, lines, triangles, quadrangles, tetrahedra, hexahedra,
/// prisms, pyramids) with their node counts; and every node an element
/// names is defined. Sections other than $MeshFormat, $PhysicalNames,
/// $Entities, $Nodes and $Elements are refused (gmsh parses some of them,
/// e.g. $Periodic names nodes, and cutsim reads none of them).
void CheckMshBeforeGmsh(const std::string& path, const std::string& bytes);

}  // namespace cutsim::mesh::internal
