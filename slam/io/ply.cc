#include "slam/io/ply.h"

#include <cstring>
#include <sstream>

#include "slam/io/file_util.h"

namespace twist::io {
namespace {

struct Property {
  std::string name;
  std::string type;  // char uchar short ushort int uint float double (and int8.. aliases)
  bool is_list = false;
  std::string count_type;
};

int TypeSize(const std::string& t) {
  if (t == "char" || t == "uchar" || t == "int8" || t == "uint8") return 1;
  if (t == "short" || t == "ushort" || t == "int16" || t == "uint16") return 2;
  if (t == "int" || t == "uint" || t == "float" || t == "int32" || t == "uint32" ||
      t == "float32") {
    return 4;
  }
  if (t == "double" || t == "float64") return 8;
  return 0;
}

double ReadBinary(const char* p, const std::string& t) {
  if (t == "char" || t == "int8") return static_cast<int8_t>(*p);
  if (t == "uchar" || t == "uint8") return static_cast<uint8_t>(*p);
  if (t == "short" || t == "int16") {
    int16_t v;
    std::memcpy(&v, p, 2);
    return v;
  }
  if (t == "ushort" || t == "uint16") {
    uint16_t v;
    std::memcpy(&v, p, 2);
    return v;
  }
  if (t == "int" || t == "int32") {
    int32_t v;
    std::memcpy(&v, p, 4);
    return v;
  }
  if (t == "uint" || t == "uint32") {
    uint32_t v;
    std::memcpy(&v, p, 4);
    return v;
  }
  if (t == "float" || t == "float32") {
    float v;
    std::memcpy(&v, p, 4);
    return v;
  }
  double v;
  std::memcpy(&v, p, 8);
  return v;
}

void Assign(const std::string& name, double v, PlyPoint* pt) {
  if (name == "x") pt->p_in_world.x() = v;
  if (name == "y") pt->p_in_world.y() = v;
  if (name == "z") pt->p_in_world.z() = v;
  if (name == "class_id" || name == "class") pt->class_id = static_cast<int>(v);
  if (name == "cluster_id" || name == "cluster") pt->cluster_id = static_cast<int64_t>(v);
  if (name == "red") pt->r = static_cast<uint8_t>(v), pt->has_colour = true;
  if (name == "green") pt->g = static_cast<uint8_t>(v);
  if (name == "blue") pt->b = static_cast<uint8_t>(v);
}

}  // namespace

absl::StatusOr<std::vector<PlyPoint>> ReadPlyPoints(const std::string& path) {
  absl::StatusOr<std::string> data = ReadTextFile(path);
  if (!data.ok()) return data.status();
  const std::string& bytes = *data;
  if (bytes.compare(0, 3, "ply") != 0) return absl::InvalidArgumentError(path + ": not a PLY file");
  const size_t end_header = bytes.find("end_header");
  if (end_header == std::string::npos) {
    return absl::InvalidArgumentError(path + ": truncated PLY header (no end_header)");
  }
  size_t body = bytes.find('\n', end_header);
  if (body == std::string::npos) return absl::InvalidArgumentError(path + ": truncated PLY header");
  ++body;
  std::string format;
  // Elements in order; we need the vertex element and the sizes of those before it.
  struct Element {
    std::string name;
    int64_t count = 0;
    std::vector<Property> props;
  };
  std::vector<Element> elements;
  for (const TextLine& line : SplitLines(std::string_view(bytes).substr(0, end_header))) {
    const auto f = SplitFields(line.text);
    if (f.empty()) continue;
    if (f[0] == "format" && f.size() >= 2) {
      format = std::string(f[1]);
    } else if (f[0] == "element" && f.size() == 3) {
      Element e;
      e.name = std::string(f[1]);
      if (!ParseInt64(f[2], &e.count) || e.count < 0) {
        return LineError(path, line.number, "bad element count");
      }
      elements.push_back(e);
    } else if (f[0] == "property") {
      if (elements.empty()) return LineError(path, line.number, "property before any element");
      Property p;
      if (f.size() == 5 && f[1] == "list") {
        p.is_list = true;
        p.count_type = std::string(f[2]);
        p.type = std::string(f[3]);
        p.name = std::string(f[4]);
      } else if (f.size() == 3) {
        p.type = std::string(f[1]);
        p.name = std::string(f[2]);
      } else {
        return LineError(path, line.number, "malformed property line");
      }
      if (TypeSize(p.type) == 0 || (p.is_list && TypeSize(p.count_type) == 0)) {
        return LineError(path, line.number, "unknown PLY type");
      }
      elements.back().props.push_back(p);
    }
  }
  if (format != "ascii" && format != "binary_little_endian") {
    return absl::InvalidArgumentError(path + ": unsupported PLY format '" + format +
                                      "' (ascii or binary_little_endian)");
  }
  std::vector<PlyPoint> points;
  if (format == "ascii") {
    std::vector<TextLine> lines = SplitLines(std::string_view(bytes).substr(body));
    size_t li = 0;
    for (const Element& e : elements) {
      for (int64_t k = 0; k < e.count; ++k, ++li) {
        if (li >= lines.size()) {
          return absl::InvalidArgumentError(path + ": truncated: element " + e.name + " has " +
                                            std::to_string(k) + " of " + std::to_string(e.count) +
                                            " rows");
        }
        if (e.name != "vertex") continue;
        const auto f = SplitFields(lines[li].text);
        PlyPoint pt;
        size_t fi = 0;
        for (const Property& p : e.props) {
          if (p.is_list) {
            double n = 0;
            if (fi >= f.size() || !ParseDouble(f[fi], &n)) break;
            fi += 1 + static_cast<size_t>(n);
            continue;
          }
          double v = 0;
          if (fi >= f.size() || !ParseDouble(f[fi], &v)) {
            return absl::InvalidArgumentError(path + ": malformed vertex row " + std::to_string(k) +
                                              " (property " + p.name + ")");
          }
          Assign(p.name, v, &pt);
          ++fi;
        }
        points.push_back(pt);
      }
    }
    return points;
  }
  size_t off = body;
  for (const Element& e : elements) {
    for (int64_t k = 0; k < e.count; ++k) {
      PlyPoint pt;
      for (const Property& p : e.props) {
        if (p.is_list) {
          const int cs = TypeSize(p.count_type);
          if (off + cs > bytes.size()) goto truncated;
          const int64_t n = static_cast<int64_t>(ReadBinary(bytes.data() + off, p.count_type));
          off += cs + n * TypeSize(p.type);
          continue;
        }
        const int s = TypeSize(p.type);
        if (off + s > bytes.size()) goto truncated;
        if (e.name == "vertex") Assign(p.name, ReadBinary(bytes.data() + off, p.type), &pt);
        off += s;
      }
      if (e.name == "vertex") points.push_back(pt);
    }
  }
  return points;
truncated:
  return absl::InvalidArgumentError(path + ": truncated binary PLY body");
}

absl::Status WritePlyPoints(const std::string& path, const std::vector<PlyPoint>& points) {
  std::ostringstream out;
  out << "ply\nformat ascii 1.0\nelement vertex " << points.size()
      << "\nproperty double x\nproperty double y\nproperty double z\n"
         "property int class_id\nproperty int cluster_id\n"
         "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n";
  out.precision(9);
  for (const PlyPoint& p : points) {
    out << p.p_in_world.x() << ' ' << p.p_in_world.y() << ' ' << p.p_in_world.z() << ' '
        << p.class_id << ' ' << p.cluster_id << ' ' << static_cast<int>(p.r) << ' '
        << static_cast<int>(p.g) << ' ' << static_cast<int>(p.b) << '\n';
  }
  return WriteFileAtomic(path, out.str());
}

}  // namespace twist::io
