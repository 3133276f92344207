#include "slam/joints/class_table.h"

#include <cmath>
#include <set>
#include <sstream>
#include <string_view>
#include <utility>

#include "absl/strings/ascii.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "absl/strings/string_view.h"
#include "glog/logging.h"

namespace twist::joints {
namespace {

std::string Describe(const ClassInfo& c) {
  return absl::StrCat("class '", c.name, "' (id ", c.id, ")");
}

bool IsValidName(absl::string_view name) {
  if (name.empty()) return false;
  bool all_digits = true;
  for (char ch : name) {
    if (!absl::ascii_isalnum(ch) && ch != '_' && ch != '-') return false;
    if (!absl::ascii_isdigit(ch)) all_digits = false;
  }
  return !all_digits;  // all-digit names would be ambiguous with ids
}

bool NeedsPlaneParent(JointType type) {
  return type == JointType::kPlanar || type == JointType::kPointContact;
}

// Validates `classes`; on error sets *bad_index to the offending class.
absl::Status ValidateClasses(const std::vector<ClassInfo>& classes, size_t* bad_index) {
  std::map<int, size_t> by_id;
  std::map<std::string, size_t> by_name;
  for (size_t i = 0; i < classes.size(); ++i) {
    const ClassInfo& c = classes[i];
    *bad_index = i;
    if (c.id < 0) return absl::InvalidArgumentError(absl::StrCat(Describe(c), ": id must be >= 0"));
    if (!IsValidName(c.name)) {
      return absl::InvalidArgumentError(
          absl::StrCat("class id ",
                       c.id,
                       ": invalid name '",
                       c.name,
                       "' (letters, digits, '_' or '-', not only digits)"));
    }
    if (!by_id.emplace(c.id, i).second) {
      return absl::InvalidArgumentError(absl::StrCat(Describe(c),
                                                     ": duplicate id ",
                                                     c.id,
                                                     " (also used by '",
                                                     classes[by_id[c.id]].name,
                                                     "')"));
    }
    if (!by_name.emplace(c.name, i).second) {
      return absl::InvalidArgumentError(
          absl::StrCat(Describe(c), ": duplicate name '", c.name, "'"));
    }
  }
  for (size_t i = 0; i < classes.size(); ++i) {
    const ClassInfo& c = classes[i];
    *bad_index = i;
    const int type_index = static_cast<int>(c.joint);
    if (type_index < 0 || type_index >= kNumJointTypes) {
      return absl::InvalidArgumentError(
          absl::StrCat(Describe(c), ": invalid joint type ", type_index));
    }
    if (!std::isfinite(c.pitch)) {
      return absl::InvalidArgumentError(absl::StrCat(Describe(c), ": pitch must be finite"));
    }
    if (c.parent_id == -1) continue;
    if (by_id.find(c.parent_id) == by_id.end()) {
      return absl::InvalidArgumentError(
          absl::StrCat(Describe(c), ": unknown parent id ", c.parent_id));
    }
    // Cycle: follow the parent chain; it must end within classes.size() steps.
    std::set<int> seen = {c.id};
    std::string chain = c.name;
    for (int parent = c.parent_id; parent != -1;) {
      const auto it = by_id.find(parent);
      if (it == by_id.end()) break;  // reported for that class
      const ClassInfo& p = classes[it->second];
      absl::StrAppend(&chain, " -> ", p.name);
      if (!seen.insert(parent).second) {
        return absl::InvalidArgumentError(absl::StrCat(Describe(c), ": parent cycle ", chain));
      }
      parent = p.parent_id;
    }
  }
  for (size_t i = 0; i < classes.size(); ++i) {
    const ClassInfo& c = classes[i];
    *bad_index = i;
    if (!c.is_dynamic) {
      if (c.parent_id != -1) {
        return absl::InvalidArgumentError(absl::StrCat(
            Describe(c),
            ": static classes cannot have a parent (only dynamic classes are jointed)"));
      }
      if (c.pitch != 0.0) {
        return absl::InvalidArgumentError(
            absl::StrCat(Describe(c), ": static classes cannot have a pitch"));
      }
      continue;
    }
    if (c.fit_plane) {
      return absl::InvalidArgumentError(
          absl::StrCat(Describe(c), ": planes are fitted to static classes only"));
    }
    if (c.joint == JointType::kHelical && c.pitch == 0.0) {
      return absl::InvalidArgumentError(
          absl::StrCat(Describe(c), ": helical joint needs a non-zero pitch"));
    }
    if (c.joint != JointType::kHelical && c.pitch != 0.0) {
      return absl::InvalidArgumentError(
          absl::StrCat(Describe(c),
                       ": pitch is only meaningful for helical joints, not ",
                       JointTypeName(c.joint)));
    }
    if (c.parent_id == -1) {
      if (c.joint != JointType::kFree) {
        return absl::InvalidArgumentError(
            absl::StrCat(Describe(c),
                         ": joint ",
                         JointTypeName(c.joint),
                         " needs a parent (only 'free' works without one)"));
      }
      continue;
    }
    const ClassInfo& parent = classes[by_id[c.parent_id]];
    if (parent.is_dynamic) {
      return absl::InvalidArgumentError(absl::StrCat(
          Describe(c), ": parent ", Describe(parent), " is dynamic; parents must be static"));
    }
    if (NeedsPlaneParent(c.joint) && !parent.fit_plane) {
      return absl::InvalidArgumentError(
          absl::StrCat(Describe(c),
                       ": joint ",
                       JointTypeName(c.joint),
                       " on parent ",
                       Describe(parent),
                       " needs a plane, but planes are not fitted for the parent"));
    }
  }
  return absl::OkStatus();
}

absl::Status LineError(int line_number, absl::string_view message) {
  return absl::InvalidArgumentError(absl::StrCat("class table line ", line_number, ": ", message));
}

}  // namespace

ClassTable ClassTable::CityscapesDefault() {
  std::vector<ClassInfo> classes;
  auto add_static = [&classes](int id, const char* name, bool plane) {
    ClassInfo c;
    c.id = id;
    c.name = name;
    c.fit_plane = plane;
    classes.push_back(c);
  };
  auto add_dynamic = [&classes](int id, const char* name, int parent, JointType joint) {
    ClassInfo c;
    c.id = id;
    c.name = name;
    c.is_dynamic = true;
    c.parent_id = parent;
    c.joint = joint;
    classes.push_back(c);
  };
  constexpr int kRoad = 7;
  constexpr int kWall = 12;
  add_static(kRoad, "road", true);
  add_static(8, "sidewalk", true);
  add_static(11, "building", true);
  add_static(kWall, "wall", true);
  add_static(13, "fence", false);
  add_static(17, "pole", false);
  add_static(21, "vegetation", false);
  add_static(22, "terrain", false);
  add_static(23, "sky", false);
  add_dynamic(24, "person", kRoad, JointType::kPlanar);
  add_dynamic(25, "rider", kRoad, JointType::kPlanar);
  add_dynamic(26, "car", kRoad, JointType::kPlanar);
  add_dynamic(27, "truck", kRoad, JointType::kPlanar);
  add_dynamic(28, "bus", kRoad, JointType::kPlanar);
  add_dynamic(31, "train", kRoad, JointType::kPlanar);
  add_dynamic(32, "motorcycle", kRoad, JointType::kPlanar);
  add_dynamic(33, "bicycle", kRoad, JointType::kPlanar);
  add_dynamic(40, "door", kWall, JointType::kRevolute);
  absl::StatusOr<ClassTable> table = Create(std::move(classes));
  CHECK(table.ok()) << table.status();
  return *std::move(table);
}

absl::StatusOr<ClassTable> ClassTable::FromText(const std::string& text) {
  std::vector<ClassInfo> classes;
  std::vector<int> line_of_class;
  // Parents may be named before they are defined: resolve after reading.
  std::vector<std::string> parent_refs;
  std::set<std::string> static_with_joint;
  int line_number = 0;
  for (absl::string_view raw_line : absl::StrSplit(text, '\n')) {
    ++line_number;
    absl::string_view line = raw_line.substr(0, raw_line.find('#'));
    const std::vector<absl::string_view> tokens =
        absl::StrSplit(line, absl::ByAnyChar(" \t\r"), absl::SkipEmpty());
    if (tokens.empty()) continue;
    if (tokens.size() < 3) {
      return LineError(line_number,
                       absl::StrCat("expected '<id> <name> static|dynamic [parent=<name|id>] "
                                    "[joint=<type>] [pitch=<m/rad>] [plane]', got '",
                                    absl::StripAsciiWhitespace(line),
                                    "'"));
    }
    ClassInfo c;
    if (!absl::SimpleAtoi(tokens[0], &c.id) || c.id < 0) {
      return LineError(
          line_number,
          absl::StrCat("class id must be a non-negative integer, got '", tokens[0], "'"));
    }
    c.name = std::string(tokens[1]);
    if (!IsValidName(c.name)) {
      return LineError(
          line_number,
          absl::StrCat(
              "invalid class name '", c.name, "' (letters, digits, '_' or '-', not only digits)"));
    }
    if (tokens[2] == "static") {
      c.is_dynamic = false;
    } else if (tokens[2] == "dynamic") {
      c.is_dynamic = true;
    } else {
      return LineError(
          line_number,
          absl::StrCat("third field must be 'static' or 'dynamic', got '", tokens[2], "'"));
    }
    std::string parent_ref;
    bool has_joint = false;
    bool has_pitch = false;
    for (size_t t = 3; t < tokens.size(); ++t) {
      const absl::string_view token = tokens[t];
      if (token == "plane") {
        if (c.fit_plane) return LineError(line_number, "'plane' given twice");
        c.fit_plane = true;
        continue;
      }
      const size_t eq = token.find('=');
      if (eq == absl::string_view::npos || eq + 1 == token.size()) {
        return LineError(line_number,
                         absl::StrCat("unknown attribute '",
                                      token,
                                      "' (expected parent=..., joint=..., pitch=... or plane)"));
      }
      const absl::string_view key = token.substr(0, eq);
      const absl::string_view value = token.substr(eq + 1);
      if (key == "parent") {
        if (!parent_ref.empty()) return LineError(line_number, "'parent=' given twice");
        parent_ref = std::string(value);
      } else if (key == "joint") {
        if (has_joint) return LineError(line_number, "'joint=' given twice");
        absl::StatusOr<JointType> joint =
            JointTypeFromName(std::string_view(value.data(), value.size()));
        if (!joint.ok()) return LineError(line_number, joint.status().message());
        c.joint = *joint;
        has_joint = true;
      } else if (key == "pitch") {
        if (has_pitch) return LineError(line_number, "'pitch=' given twice");
        if (!absl::SimpleAtod(value, &c.pitch) || !std::isfinite(c.pitch)) {
          return LineError(
              line_number,
              absl::StrCat("pitch must be a finite number (m/rad), got '", value, "'"));
        }
        has_pitch = true;
      } else {
        return LineError(
            line_number,
            absl::StrCat(
                "unknown attribute '", key, "=' (expected parent=, joint=, pitch= or plane)"));
      }
    }
    if (!c.is_dynamic && (has_joint || !parent_ref.empty())) {
      return LineError(
          line_number,
          absl::StrCat("static class '",
                       c.name,
                       "' cannot have a parent or a joint (only dynamic classes move)"));
    }
    classes.push_back(c);
    line_of_class.push_back(line_number);
    parent_refs.push_back(parent_ref);
  }

  // Resolve parents by id or name.
  std::map<std::string, int> id_by_name;
  for (const ClassInfo& c : classes) id_by_name.emplace(c.name, c.id);
  for (size_t i = 0; i < classes.size(); ++i) {
    const std::string& ref = parent_refs[i];
    if (ref.empty()) continue;
    int parent_id = -1;
    if (absl::SimpleAtoi(ref, &parent_id)) {
      if (parent_id < 0) {
        return LineError(line_of_class[i], absl::StrCat("parent id must be >= 0, got ", parent_id));
      }
    } else {
      const auto it = id_by_name.find(ref);
      if (it == id_by_name.end()) {
        return LineError(line_of_class[i],
                         absl::StrCat("class '", classes[i].name, "': unknown parent '", ref, "'"));
      }
      parent_id = it->second;
    }
    classes[i].parent_id = parent_id;
  }

  size_t bad_index = 0;
  const absl::Status status = ValidateClasses(classes, &bad_index);
  if (!status.ok()) return LineError(line_of_class[bad_index], status.message());
  return Create(std::move(classes));
}

std::string ClassTable::ToText() const {
  std::ostringstream os;
  os << "# id name static|dynamic [parent=<name|id>] [joint=<type>] [pitch=<m/rad>] [plane]\n";
  for (const ClassInfo& c : classes_) {
    os << c.id << ' ' << c.name << ' ' << (c.is_dynamic ? "dynamic" : "static");
    if (c.parent_id != -1) {
      const ClassInfo* parent = Find(c.parent_id);
      os << " parent=" << (parent != nullptr ? parent->name : std::to_string(c.parent_id));
    }
    if (c.is_dynamic) os << " joint=" << JointTypeName(c.joint);
    if (c.pitch != 0.0) {
      std::ostringstream pitch;
      pitch.precision(17);
      pitch << c.pitch;
      os << " pitch=" << pitch.str();
    }
    if (c.fit_plane) os << " plane";
    os << '\n';
  }
  return os.str();
}

absl::StatusOr<ClassTable> ClassTable::Create(std::vector<ClassInfo> classes) {
  size_t bad_index = 0;
  const absl::Status status = ValidateClasses(classes, &bad_index);
  if (!status.ok()) return status;
  ClassTable table;
  table.classes_ = std::move(classes);
  for (size_t i = 0; i < table.classes_.size(); ++i) table.index_[table.classes_[i].id] = i;
  return table;
}

absl::Status ClassTable::Validate() const {
  size_t bad_index = 0;
  return ValidateClasses(classes_, &bad_index);
}

const ClassInfo* ClassTable::Find(int class_id) const {
  const auto it = index_.find(class_id);
  return it == index_.end() ? nullptr : &classes_[it->second];
}

bool ClassTable::IsDynamic(int class_id) const {
  const ClassInfo* c = Find(class_id);
  return c != nullptr && c->is_dynamic;
}

}  // namespace twist::joints
