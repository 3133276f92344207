// Map snapshot -> PLY (ASCII, binary-free so any viewer and a diff can read
// it): one vertex per map point with a colour per semantic class, its class id
// and cluster id, then the keyframe camera centres in white (class_id -1).
#pragma once

#include <string>

#include "slam/system/slam_system.h"

namespace twist::client {

std::string MapToPly(const MapSnapshot& map);

}  // namespace twist::client
