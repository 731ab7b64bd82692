// The non-template code of Boost.Asio and Boost.Beast, compiled once for the
// whole program (CMakeLists.txt defines the *_SEPARATE_COMPILATION macros
// for every target that links cutsim::net).
#include <boost/asio/impl/src.hpp>
#include <boost/beast/src.hpp>
