#include "slam/joints/class_table.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <string>

namespace twist::joints {
namespace {

using ::testing::HasSubstr;

// Expects `text` to be rejected with a message containing every fragment.
void ExpectParseError(const std::string& text, const std::vector<std::string>& fragments) {
  const absl::StatusOr<ClassTable> table = ClassTable::FromText(text);
  ASSERT_FALSE(table.ok()) << "accepted:\n" << text;
  EXPECT_EQ(table.status().code(), absl::StatusCode::kInvalidArgument);
  for (const std::string& fragment : fragments) {
    EXPECT_THAT(std::string(table.status().message()), HasSubstr(fragment)) << text;
  }
}

ClassInfo Static(int id, const std::string& name, bool plane = false) {
  ClassInfo c;
  c.id = id;
  c.name = name;
  c.fit_plane = plane;
  return c;
}

ClassInfo Dynamic(int id, const std::string& name, int parent, JointType joint) {
  ClassInfo c;
  c.id = id;
  c.name = name;
  c.is_dynamic = true;
  c.parent_id = parent;
  c.joint = joint;
  return c;
}

TEST(ClassTableTest, CityscapesDefault) {
  const ClassTable table = ClassTable::CityscapesDefault();
  EXPECT_TRUE(table.Validate().ok());
  for (int id : {24, 25, 26, 27, 28, 31, 32, 33}) {
    const ClassInfo* c = table.Find(id);
    ASSERT_NE(c, nullptr) << id;
    EXPECT_TRUE(c->is_dynamic);
    EXPECT_TRUE(table.IsDynamic(id));
    EXPECT_EQ(c->parent_id, 7) << c->name;
    EXPECT_EQ(c->joint, JointType::kPlanar) << c->name;
  }
  for (int id : {7, 8, 11, 12, 13, 17, 21, 22, 23}) {
    ASSERT_NE(table.Find(id), nullptr) << id;
    EXPECT_FALSE(table.IsDynamic(id));
  }
  EXPECT_EQ(table.Find(26)->name, "car");
  EXPECT_TRUE(table.Find(7)->fit_plane);
  EXPECT_TRUE(table.Find(12)->fit_plane);
  const ClassInfo* door = table.Find(40);
  ASSERT_NE(door, nullptr);
  EXPECT_EQ(door->name, "door");
  EXPECT_EQ(door->joint, JointType::kRevolute);
  EXPECT_EQ(door->parent_id, 12);
  // Unknown classes are static.
  EXPECT_EQ(table.Find(999), nullptr);
  EXPECT_FALSE(table.IsDynamic(999));
}

TEST(ClassTableTest, TextRoundTrip) {
  const ClassTable table = ClassTable::CityscapesDefault();
  const absl::StatusOr<ClassTable> parsed = ClassTable::FromText(table.ToText());
  ASSERT_TRUE(parsed.ok()) << parsed.status();
  ASSERT_EQ(parsed->classes().size(), table.classes().size());
  for (size_t i = 0; i < table.classes().size(); ++i) {
    const ClassInfo& a = table.classes()[i];
    const ClassInfo& b = parsed->classes()[i];
    EXPECT_EQ(a.id, b.id);
    EXPECT_EQ(a.name, b.name);
    EXPECT_EQ(a.is_dynamic, b.is_dynamic);
    EXPECT_EQ(a.parent_id, b.parent_id);
    EXPECT_EQ(a.joint, b.joint);
    EXPECT_EQ(a.pitch, b.pitch);
    EXPECT_EQ(a.fit_plane, b.fit_plane);
  }
}

TEST(ClassTableTest, ParsesCommentsForwardParentsIdsAndPitch) {
  const absl::StatusOr<ClassTable> table = ClassTable::FromText(
      "# a small scene\n"
      "\n"
      "  5 screw   dynamic parent=plate joint=helical pitch=-0.002  # forward reference\n"
      "3 plate static plane\n"
      "4 ball dynamic parent=3 joint=spherical\n"
      "\t9 drone dynamic joint=free\n"
      "10 cart dynamic parent=plate joint=Point-Contact\r\n");
  ASSERT_TRUE(table.ok()) << table.status();
  ASSERT_EQ(table->classes().size(), 5u);
  const ClassInfo* screw = table->Find(5);
  ASSERT_NE(screw, nullptr);
  EXPECT_EQ(screw->parent_id, 3);
  EXPECT_EQ(screw->joint, JointType::kHelical);
  EXPECT_DOUBLE_EQ(screw->pitch, -0.002);
  EXPECT_EQ(table->Find(4)->parent_id, 3);
  EXPECT_EQ(table->Find(9)->parent_id, -1);
  EXPECT_EQ(table->Find(10)->joint, JointType::kPointContact);
  EXPECT_TRUE(table->Find(3)->fit_plane);
  EXPECT_FALSE(table->Find(3)->is_dynamic);
}

TEST(ClassTableTest, SyntaxErrorsNameTheLine) {
  ExpectParseError("7 road static\n26 car\n", {"line 2", "static|dynamic"});
  ExpectParseError("x road static\n", {"line 1", "'x'"});
  ExpectParseError("-3 road static\n", {"line 1", "non-negative"});
  ExpectParseError("7 road moving\n", {"line 1", "'moving'"});
  ExpectParseError("7 123 static\n", {"line 1", "invalid class name"});
  ExpectParseError("7 road static plane\n26 car dynamic parent=road joint=hinge\n",
                   {"line 2", "hinge"});
  ExpectParseError("7 road static plane\n26 car dynamic parent=road color=red\n",
                   {"line 2", "color"});
  ExpectParseError("7 road static plane\n26 car dynamic parent=road joint=planar speed\n",
                   {"line 2", "speed"});
  ExpectParseError("7 road static\n\n5 s dynamic parent=road joint=helical pitch=abc\n",
                   {"line 3", "pitch"});
  ExpectParseError("7 road static plane plane\n", {"line 1", "twice"});
  ExpectParseError("7 road static plane\n26 car dynamic parent=road parent=7 joint=planar\n",
                   {"line 2", "twice"});
}

TEST(ClassTableTest, SemanticErrorsNameTheLineAndClass) {
  // Unknown parent, by name and by id.
  ExpectParseError("7 road static plane\n26 car dynamic parent=street joint=planar\n",
                   {"line 2", "car", "unknown parent 'street'"});
  ExpectParseError("7 road static plane\n26 car dynamic parent=8 joint=planar\n",
                   {"line 2", "car", "unknown parent id 8"});
  // Dynamic parent.
  ExpectParseError(
      "7 road static plane\n26 car dynamic parent=road joint=planar\n"
      "50 trailer dynamic parent=car joint=spherical\n",
      {"line 3", "trailer", "dynamic"});
  // Cycle (a dynamic class that is its own parent, and a two-class loop).
  ExpectParseError("26 car dynamic parent=car joint=free\n", {"line 1", "cycle"});
  ExpectParseError("1 a dynamic parent=b joint=free\n2 b dynamic parent=a joint=free\n",
                   {"cycle", "a -> b -> a"});
  // Duplicates.
  ExpectParseError("7 road static\n7 street static\n", {"line 2", "duplicate id 7"});
  ExpectParseError("7 road static\n8 road static\n", {"line 2", "duplicate name 'road'"});
  // Static class with a joint or a parent.
  ExpectParseError("7 road static joint=planar\n", {"line 1", "static class 'road'"});
  ExpectParseError("7 road static\n8 sidewalk static parent=road\n",
                   {"line 2", "static class 'sidewalk'"});
  // Joint needs a parent / a plane; pitch only for helical; planes only for static classes.
  ExpectParseError("26 car dynamic joint=planar\n", {"line 1", "needs a parent"});
  ExpectParseError("7 road static\n26 car dynamic parent=road joint=planar\n", {"line 2", "plane"});
  ExpectParseError("12 wall static plane\n40 door dynamic parent=wall joint=revolute pitch=0.1\n",
                   {"line 2", "helical"});
  ExpectParseError("12 wall static plane\n41 screw dynamic parent=wall joint=helical\n",
                   {"line 2", "pitch"});
  ExpectParseError("26 car dynamic joint=free plane\n", {"line 1", "static classes only"});
}

TEST(ClassTableTest, CreateValidates) {
  EXPECT_TRUE(
      ClassTable::Create({Static(7, "road", true), Dynamic(26, "car", 7, JointType::kPlanar)})
          .ok());
  EXPECT_TRUE(ClassTable::Create({}).ok());

  auto expect_error = [](std::vector<ClassInfo> classes, const std::string& fragment) {
    const absl::StatusOr<ClassTable> table = ClassTable::Create(std::move(classes));
    ASSERT_FALSE(table.ok()) << fragment;
    EXPECT_EQ(table.status().code(), absl::StatusCode::kInvalidArgument);
    EXPECT_THAT(std::string(table.status().message()), HasSubstr(fragment));
  };
  expect_error({Static(7, "road", true), Dynamic(26, "car", 70, JointType::kPlanar)},
               "unknown parent id 70");
  expect_error({Static(7, "road", true),
                Dynamic(26, "car", 7, JointType::kPlanar),
                Dynamic(27, "trailer", 26, JointType::kFree)},
               "is dynamic");
  expect_error({Dynamic(1, "a", 2, JointType::kFree), Dynamic(2, "b", 1, JointType::kFree)},
               "cycle");
  expect_error({Static(7, "road"), Static(7, "street")}, "duplicate id");
  expect_error({Static(7, "road"), Static(8, "road")}, "duplicate name");
  ClassInfo static_with_parent = Static(8, "sidewalk");
  static_with_parent.parent_id = 7;
  expect_error({Static(7, "road"), static_with_parent}, "static classes cannot have a parent");
  expect_error({Static(7, "")}, "invalid name");
  ClassInfo bad_joint = Dynamic(26, "car", -1, JointType::kFree);
  bad_joint.joint = static_cast<JointType>(42);
  expect_error({bad_joint}, "invalid joint type");
}

}  // namespace
}  // namespace twist::joints
