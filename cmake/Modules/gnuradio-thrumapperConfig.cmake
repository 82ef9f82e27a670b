find_package(PkgConfig)

PKG_CHECK_MODULES(PC_GR_THRUMAPPER gnuradio-thrumapper)

FIND_PATH(
    GR_THRUMAPPER_INCLUDE_DIRS
    NAMES gnuradio/thrumapper/api.h
    HINTS $ENV{THRUMAPPER_DIR}/include
        ${PC_THRUMAPPER_INCLUDEDIR}
    PATHS ${CMAKE_INSTALL_PREFIX}/include
          /usr/local/include
          /usr/include
)

FIND_LIBRARY(
    GR_THRUMAPPER_LIBRARIES
    NAMES gnuradio-thrumapper
    HINTS $ENV{THRUMAPPER_DIR}/lib
        ${PC_THRUMAPPER_LIBDIR}
    PATHS ${CMAKE_INSTALL_PREFIX}/lib
          ${CMAKE_INSTALL_PREFIX}/lib64
          /usr/local/lib
          /usr/local/lib64
          /usr/lib
          /usr/lib64
          )

include("${CMAKE_CURRENT_LIST_DIR}/gnuradio-thrumapperTarget.cmake")

INCLUDE(FindPackageHandleStandardArgs)
FIND_PACKAGE_HANDLE_STANDARD_ARGS(GR_THRUMAPPER DEFAULT_MSG GR_THRUMAPPER_LIBRARIES GR_THRUMAPPER_INCLUDE_DIRS)
MARK_AS_ADVANCED(GR_THRUMAPPER_LIBRARIES GR_THRUMAPPER_INCLUDE_DIRS)
