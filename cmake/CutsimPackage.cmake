# Install rules and the Debian package (`cpack -G DEB`, deploy/package.sh).
#
# Installed tree (FHS; CMAKE_INSTALL_PREFIX=/usr for the package):
#   bin/cutsim-{server,haptic,viewer}
#   lib/<multiarch>/cutsim/devices/libcutsim_device_*.so   haptic device plugins
#   share/cutsim/scenes/                                   shipped scenes and tool paths
#   share/cutsim/web/{common,observer,trainee}/            browser pages, prebuilt
#   share/cutsim/web/observer/node_modules/three/          the three.js files they load
#   share/cutsim/dds/                                      Cyclone DDS configurations
#   share/doc/cutsim/                                      README, lab guide, device guide
#   share/man/man1/cutsim-{server,haptic,viewer}.1.gz      man pages from each program's --help
#   /etc/cutsim/cutsim.env                                 the lab's settings (a conffile)
#   /lib/systemd/system/cutsim-{server,haptic,bridge}@.service, cutsim-lab.service
# The web folder keeps the source tree's layout, so the apps resolve the same
# relative paths in both (common/core/install_paths.h finds share/cutsim
# beside bin/). Under /usr the configuration and the units go to /etc and
# /lib/systemd/system, as Debian has them; under any other prefix they stay
# inside it, so `cmake --install --prefix DIR` writes nothing outside DIR.

if(CMAKE_INSTALL_PREFIX STREQUAL "/usr")
  set(CUTSIM_INSTALL_CONFDIR /etc/cutsim)
  set(CUTSIM_INSTALL_UNITDIR /lib/systemd/system)
else()
  set(CUTSIM_INSTALL_CONFDIR ${CMAKE_INSTALL_SYSCONFDIR}/cutsim)
  set(CUTSIM_INSTALL_UNITDIR lib/systemd/system)
endif()

# ---- Programs and device plugins -------------------------------------------
install(TARGETS cutsim-server cutsim-haptic cutsim-viewer RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
foreach(plugin example_spring evdev spacenav)
  if(TARGET cutsim_device_${plugin})
    install(TARGETS cutsim_device_${plugin} LIBRARY DESTINATION ${CUTSIM_INSTALL_PLUGINDIR})
  endif()
endforeach()

# ---- Data: scenes, web pages, DDS configurations ----------------------------
install(DIRECTORY ${PROJECT_SOURCE_DIR}/scenes/ DESTINATION ${CUTSIM_INSTALL_DATADIR}/scenes
  PATTERN "*.sh" EXCLUDE)
# Every page under web/ (new pages come with it), without tests or npm's tree.
install(DIRECTORY ${PROJECT_SOURCE_DIR}/web/ DESTINATION ${CUTSIM_INSTALL_DATADIR}/web
  FILES_MATCHING PATTERN "*.html" PATTERN "*.js" PATTERN "*.css"
  PATTERN "test" EXCLUDE PATTERN "node_modules" EXCLUDE)
# The three.js files the pages import (npm ci in web/observer, run by
# deploy/install-deps.sh), with its licence: no npm on a lab machine.
set(_three ${PROJECT_SOURCE_DIR}/web/observer/node_modules/three)
set(_three_files build/three.module.js build/three.core.js examples/jsm/controls/OrbitControls.js LICENSE package.json)
# Checked when installing, before they are copied (the build does not need
# them): an install without them would serve pages that cannot load.
install(CODE "
  foreach(f ${_three_files})
    if(NOT EXISTS \"${_three}/\${f}\")
      message(FATAL_ERROR \"cutsim install: ${_three}/\${f} is missing: run deploy/install-deps.sh (npm ci in web/observer)\")
    endif()
  endforeach()")
foreach(f ${_three_files})
  get_filename_component(_dir ${f} DIRECTORY)
  install(FILES ${_three}/${f} DESTINATION ${CUTSIM_INSTALL_DATADIR}/web/observer/node_modules/three/${_dir})
endforeach()
install(FILES ${PROJECT_SOURCE_DIR}/deploy/cyclonedds-loopback.xml ${PROJECT_SOURCE_DIR}/deploy/cyclonedds-lan.xml
  ${PROJECT_SOURCE_DIR}/deploy/cyclonedds-unicast.xml DESTINATION ${CUTSIM_INSTALL_DATADIR}/dds)
install(FILES ${PROJECT_SOURCE_DIR}/README.md ${PROJECT_SOURCE_DIR}/docs/devices.md DESTINATION ${CMAKE_INSTALL_DOCDIR})
install(FILES ${PROJECT_SOURCE_DIR}/deploy/README.md DESTINATION ${CMAKE_INSTALL_DOCDIR} RENAME lab-guide.md)

# ---- Man pages ----------------------------------------------------------------
# One per program, made at build time from its own --help (help2man, from
# deploy/install-deps.sh), so a page cannot drift from its program. The
# bridge and the lab page are modes of cutsim-viewer, on its page.
find_program(CUTSIM_HELP2MAN help2man)
if(CUTSIM_HELP2MAN)
  set(_man_out ${PROJECT_BINARY_DIR}/man/man1)
  set(_man_pages)
  foreach(program cutsim-server cutsim-haptic cutsim-viewer)
    add_custom_command(OUTPUT ${_man_out}/${program}.1.gz
      COMMAND ${CMAKE_COMMAND} -E make_directory ${_man_out}
      COMMAND ${PROJECT_SOURCE_DIR}/cmake/man_page.sh $<TARGET_FILE:${program}> ${_man_out}/${program}.1.gz
              ${PROJECT_VERSION}
      DEPENDS ${program} ${PROJECT_SOURCE_DIR}/cmake/man_page.sh
      COMMENT "Man page of ${program} from its --help" VERBATIM)
    list(APPEND _man_pages ${_man_out}/${program}.1.gz)
  endforeach()
  add_custom_target(cutsim-man ALL DEPENDS ${_man_pages})
  install(FILES ${_man_pages} DESTINATION ${CMAKE_INSTALL_MANDIR}/man1)
else()
  message(WARNING "help2man not found (deploy/install-deps.sh installs it): no man pages are made or installed")
endif()

# ---- systemd units and the lab's environment file ---------------------------
# The units name the installed paths of this configuration (the prefix set at
# configure time), never a source tree.
set(CUTSIM_UNIT_BINDIR ${CMAKE_INSTALL_FULL_BINDIR})
set(CUTSIM_UNIT_DATADIR ${CMAKE_INSTALL_FULL_DATADIR}/cutsim)
set(CUTSIM_UNIT_DOCDIR ${CMAKE_INSTALL_FULL_DOCDIR})
if(IS_ABSOLUTE ${CUTSIM_INSTALL_CONFDIR})
  set(CUTSIM_UNIT_CONFDIR ${CUTSIM_INSTALL_CONFDIR})
else()
  set(CUTSIM_UNIT_CONFDIR ${CMAKE_INSTALL_PREFIX}/${CUTSIM_INSTALL_CONFDIR})
endif()
set(_units_out ${PROJECT_BINARY_DIR}/deploy/systemd)
foreach(unit cutsim-server@.service cutsim-haptic@.service cutsim-bridge@.service cutsim-lab.service)
  configure_file(${PROJECT_SOURCE_DIR}/deploy/systemd/${unit}.in ${_units_out}/${unit} @ONLY)
  install(FILES ${_units_out}/${unit} DESTINATION ${CUTSIM_INSTALL_UNITDIR})
endforeach()
configure_file(${PROJECT_SOURCE_DIR}/deploy/systemd/cutsim.env.in ${_units_out}/cutsim.env @ONLY)
install(FILES ${_units_out}/cutsim.env DESTINATION ${CUTSIM_INSTALL_CONFDIR})

# ---- The Debian package -----------------------------------------------------
set(CUTSIM_PACKAGE_MAINTAINER "cutsim maintainers <maintainers@users.noreply.h-seed-0180e024.example>"
  CACHE STRING "Maintainer field of the Debian package")
set(CPACK_GENERATOR DEB)
set(CPACK_PACKAGE_NAME cutsim)
set(CPACK_PACKAGE_VERSION ${PROJECT_VERSION})
set(CPACK_PACKAGE_CONTACT ${CUTSIM_PACKAGE_MAINTAINER})
set(CPACK_PACKAGE_DESCRIPTION_SUMMARY "networked surgical-cutting simulator (FEM server, haptic station, viewers)")
# The summary is the Description's first line; this is the text under it.
set(CPACK_PACKAGE_DESCRIPTION
  "cutsim simulates cutting soft tissue with a force-feedback device: a\nfinite-element server, a 1 kHz haptic station and viewers that render the\nsession or serve it to browsers. systemd units run one session per instance.")
set(CPACK_DEBIAN_PACKAGE_SECTION science)
set(CPACK_DEBIAN_FILE_NAME DEB-DEFAULT)
# The package installs where this tree was configured to (/usr).
set(CPACK_PACKAGING_INSTALL_PREFIX ${CMAKE_INSTALL_PREFIX})
set(CPACK_STRIP_FILES ON)
# Dependencies: dpkg-shlibdeps reads every binary's and plugin's libraries.
set(CPACK_DEBIAN_PACKAGE_SHLIBDEPS ON)
set(CPACK_DEBIAN_PACKAGE_RECOMMENDS "systemd")
set(CPACK_DEBIAN_PACKAGE_SUGGESTS "liblcm-bin, chromium, sqlite3")
configure_file(${PROJECT_SOURCE_DIR}/deploy/debian/conffiles.in ${PROJECT_BINARY_DIR}/deploy/debian/conffiles @ONLY)
set(CPACK_DEBIAN_PACKAGE_CONTROL_EXTRA
  ${PROJECT_BINARY_DIR}/deploy/debian/conffiles
  ${PROJECT_SOURCE_DIR}/deploy/debian/postinst
  ${PROJECT_SOURCE_DIR}/deploy/debian/prerm
  ${PROJECT_SOURCE_DIR}/deploy/debian/postrm)
set(CPACK_DEBIAN_PACKAGE_CONTROL_STRICT_PERMISSION ON)
include(CPack)
