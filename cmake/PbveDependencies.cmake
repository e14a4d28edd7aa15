# Third-party dependencies, all from Debian packages (scripts/install-deps.sh installs them).
find_package(Eigen3 3.4 REQUIRED NO_MODULE)
find_package(OpenCV 4 REQUIRED COMPONENTS core imgproc imgcodecs videoio photo video calib3d features2d)
find_package(Threads REQUIRED)
find_package(embree 3 REQUIRED)
find_package(TBB REQUIRED)
find_package(NLopt REQUIRED)
find_package(PkgConfig REQUIRED)
pkg_check_modules(IPOPT REQUIRED IMPORTED_TARGET ipopt)
find_package(yaml-cpp REQUIRED)
# Sparse Cholesky factorization for mass_spring's direct solver: CHOLMOD (libsuitesparse-dev),
# running on the system BLAS/LAPACK (libopenblas-dev for speed). PbveCholmod.cmake is also
# installed with the package configuration, which needs it for a static pbve.
include(${CMAKE_CURRENT_LIST_DIR}/PbveCholmod.cmake)
# Report files (JSON): nlohmann-json3-dev, header-only.
find_package(nlohmann_json 3 REQUIRED)
if(PBVE_WITH_BULLET)
  # Double precision: pbve state is double, and save/restore must not round it.
  pkg_check_modules(BULLET REQUIRED IMPORTED_TARGET bullet-float64)
endif()
