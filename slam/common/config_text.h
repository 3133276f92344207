// Configuration files are read with cv::FileStorage, whose YAML parser
// insists on a "%YAML:1.0" first line. Users write plain YAML (and JSON), so
// readers pass the file text through this function and open it in memory.
#pragma once

#include <fstream>
#include <optional>
#include <sstream>
#include <string>

namespace twist {

// Returns the text ready for cv::FileStorage(text, READ | MEMORY): JSON and
// YAML with the directive are returned unchanged; plain YAML gets the
// directive prepended. nullopt when the file cannot be read.
inline std::optional<std::string> ReadConfigText(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return std::nullopt;
  std::ostringstream ss;
  ss << in.rdbuf();
  std::string text = ss.str();
  const size_t first = text.find_first_not_of(" \t\r\n");
  if (first == std::string::npos) return text;
  const bool is_json = text[first] == '{';
  const bool has_directive = text.compare(first, 5, "%YAML") == 0;
  if (!is_json && !has_directive) text = "%YAML:1.0\n" + text;
  return text;
}

}  // namespace twist
