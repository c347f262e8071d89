# The dependencies of the ROS-free core (pcr_pro_core), found in one place for the package
# (CMakeLists.txt) and for the standalone fuzz project (test/fuzz/CMakeLists.txt), which compiles
# core sources without catkin.
find_package(Eigen3 3.3 REQUIRED NO_MODULE)
find_package(yaml-cpp REQUIRED)
find_package(OpenMP REQUIRED)
find_path(NANOFLANN_INCLUDE_DIR nanoflann.hpp REQUIRED)
find_package(OpenCV 4 REQUIRED COMPONENTS core imgproc imgcodecs features2d flann calib3d)
find_package(opengv REQUIRED)
