// A small streaming JSON writer (no JSON library is installed). Produces
// indented, valid JSON; strings are escaped per RFC 8259; non-finite numbers
// are written as null.
//
//   JsonWriter w;
//   w.BeginObject().Key("rpe_t").Number(0.01).Key("name").String("06").EndObject();
//   std::string text = w.str();
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace twist::io {

std::string JsonEscape(std::string_view text);  // quoted, escaped

class JsonWriter {
 public:
  explicit JsonWriter(bool pretty = true) : pretty_(pretty) {}

  JsonWriter& BeginObject();
  JsonWriter& EndObject();
  JsonWriter& BeginArray();
  JsonWriter& EndArray();
  JsonWriter& Key(std::string_view key);
  JsonWriter& String(std::string_view value);
  JsonWriter& Number(double value);  // NaN / ±inf -> null
  JsonWriter& Int(int64_t value);
  JsonWriter& Bool(bool value);
  JsonWriter& Null();

  // The document so far; complete once every Begin has its End.
  const std::string& str() const { return out_; }
  bool complete() const { return stack_.empty() && !out_.empty(); }

 private:
  void BeforeValue();
  void Newline();

  struct Level {
    bool is_object = false;
    bool empty = true;
  };
  bool pretty_;
  std::string out_;
  std::vector<Level> stack_;
  bool after_key_ = false;
};

}  // namespace twist::io
