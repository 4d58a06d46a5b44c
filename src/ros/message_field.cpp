#include "uw_multislam/ros/message_field.h"

#include <cstring>
#include <sstream>

namespace uw_multislam {
namespace ros_bag {

namespace {

// The fixed-size primitives of the ROS serialization (little-endian), by size in bytes.
const std::map<std::string, std::size_t> kPrimitives = {{"bool", 1},    {"int8", 1},    {"uint8", 1},   {"byte", 1},
                                                        {"char", 1},    {"int16", 2},   {"uint16", 2},  {"int32", 4},
                                                        {"uint32", 4},  {"float32", 4}, {"int64", 8},   {"uint64", 8},
                                                        {"float64", 8}, {"time", 8},    {"duration", 8}};

std::string trim(const std::string& s) {
  const auto a = s.find_first_not_of(" \t\r");
  if (a == std::string::npos) return "";
  return s.substr(a, s.find_last_not_of(" \t\r") - a + 1);
}

bool builtin(const std::string& t) { return t == "string" || kPrimitives.count(t) > 0; }

// A field's type as the definition's sections name it: "Header" is std_msgs', a bare name is its own package's.
std::string resolve(const std::string& type, const std::string& package) {
  if (builtin(type) || type.find('/') != std::string::npos) return type;
  if (type == "Header") return "std_msgs/Header";
  return package + "/" + type;
}

template <typename T>
double as(const std::uint8_t* p) {
  T v;
  std::memcpy(&v, p, sizeof(T));
  return static_cast<double>(v);
}

bool readLength(const std::uint8_t** p, const std::uint8_t* end, std::uint32_t* n) {
  if (end - *p < 4) return false;
  std::memcpy(n, *p, 4);
  *p += 4;
  return true;
}

}  // namespace

MessageFields::MessageFields(const std::string& datatype, const std::string& definition) : main_(datatype) {
  std::vector<std::pair<std::string, std::vector<std::string>>> sections = {{datatype, {}}};
  std::istringstream in(definition);
  for (std::string line; std::getline(in, line);) {
    if (line.rfind("====", 0) == 0) {
      sections.emplace_back("", std::vector<std::string>());
    } else if (line.rfind("MSG: ", 0) == 0) {
      sections.back().first = trim(line.substr(5));
    } else {
      sections.back().second.push_back(line);
    }
  }
  for (const auto& [name, lines] : sections) {
    const std::string package = name.substr(0, name.find('/'));
    std::vector<Field>& fields = types_[name];
    for (std::string line : lines) {
      line = trim(line.substr(0, line.find('#')));
      if (line.empty() || line.find('=') != std::string::npos) continue;  // a comment, or a constant
      std::istringstream words(line);
      Field f;
      std::string type;
      if (!(words >> type >> f.name)) {
        why_ = name + ": cannot read the definition line '" + line + "'";
        return;
      }
      if (const auto open = type.find('['); open != std::string::npos) {
        f.array = true;
        const std::string n = type.substr(open + 1, type.size() - open - 2);
        f.fixed = n.empty() ? -1 : std::atol(n.c_str());
        type = type.substr(0, open);
      }
      f.type = resolve(type, package);
      fields.push_back(f);
    }
  }
  for (const auto& [name, fields] : types_)
    for (const Field& f : fields)
      if (!builtin(f.type) && types_.count(f.type) == 0) why_ = "the definition of " + name + " lacks " + f.type;
}

bool MessageFields::hasHeader() const {
  const auto it = types_.find(main_);
  return it != types_.end() && !it->second.empty() && it->second.front().type == "std_msgs/Header" &&
         it->second.front().name == "header";
}

std::string MessageFields::fieldList(const std::string& type) const {
  std::string list;
  for (const Field& f : types_.at(type)) list += (list.empty() ? "" : ", ") + f.name;
  return list;
}

std::size_t MessageFields::minBytes(const std::string& type) const {
  if (const auto it = kPrimitives.find(type); it != kPrimitives.end()) return it->second;
  if (type == "string") return 4;
  std::size_t n = 0;
  for (const Field& f : types_.at(type))
    n += !f.array ? minBytes(f.type) : f.fixed >= 0 ? static_cast<std::size_t>(f.fixed) * minBytes(f.type) : 4;
  return n;
}

bool MessageFields::skipMany(const std::string& type, std::uint32_t n, const std::uint8_t** p,
                             const std::uint8_t* end) const {
  // A length the bytes cannot hold fails at once (a damaged length would loop for billions of elements).
  const std::size_t least = minBytes(type);
  if (least == 0) return true;  // elements of no bytes: nothing to skip
  if (static_cast<std::size_t>(end - *p) / least < n) return false;
  for (std::uint32_t i = 0; i < n; ++i)
    if (!skip(type, p, end)) return false;
  return true;
}

bool MessageFields::skip(const std::string& type, const std::uint8_t** p, const std::uint8_t* end) const {
  if (const auto it = kPrimitives.find(type); it != kPrimitives.end()) {
    if (static_cast<std::size_t>(end - *p) < it->second) return false;
    *p += it->second;
    return true;
  }
  std::uint32_t n = 0;
  if (type == "string") {
    if (!readLength(p, end, &n) || static_cast<std::size_t>(end - *p) < n) return false;
    *p += n;
    return true;
  }
  for (const Field& f : types_.at(type)) {
    if (!f.array) {
      if (!skip(f.type, p, end)) return false;
      continue;
    }
    if (f.fixed >= 0)
      n = static_cast<std::uint32_t>(f.fixed);
    else if (!readLength(p, end, &n))
      return false;
    if (!skipMany(f.type, n, p, end)) return false;
  }
  return true;
}

bool MessageFields::find(const std::uint8_t* data, std::size_t size, const std::string& path, Value* out,
                         std::string* why) const {
  std::string error;
  auto fail = [&](const std::string& e) {
    if (why) *why = e;
    return false;
  };
  if (!ok()) return fail(why_);
  const std::uint8_t* p = data;
  const std::uint8_t* end = data + size;
  std::string type = main_;
  std::istringstream parts(path.rfind("m.", 0) == 0 ? path.substr(2) : path);  // the relay's `m.` prefix
  const std::string truncated = main_ + ": the message is shorter than its type (" + std::to_string(size) + " bytes)";
  for (std::string part; std::getline(parts, part, '.');) {
    long index = -1;
    if (const auto open = part.find('['); open != std::string::npos) {
      index = std::atol(part.c_str() + open + 1);
      part = part.substr(0, open);
    }
    if (builtin(type)) return fail("'" + path + "': " + type + " has no field '" + part + "'");
    bool found = false;
    for (const Field& f : types_.at(type)) {
      std::uint32_t n = 1;
      if (f.array) {
        if (f.fixed >= 0)
          n = static_cast<std::uint32_t>(f.fixed);
        else if (!readLength(&p, end, &n))
          return fail(truncated);
      }
      if (f.name != part) {
        if (!skipMany(f.type, n, &p, end)) return fail(truncated);
        continue;
      }
      if (f.array != (index >= 0))
        return fail("'" + path + "': " + part + (f.array ? " is an array: give an index" : " is not an array"));
      if (index >= static_cast<long>(n))
        return fail("'" + path + "': " + part + " has " + std::to_string(n) + " elements in this message");
      if (index > 0 && !skipMany(f.type, static_cast<std::uint32_t>(index), &p, end)) return fail(truncated);
      type = f.type;
      found = true;
      break;
    }
    if (!found)
      return fail("'" + path + "': " + type + " has no field '" + part + "' (it has " + fieldList(type) + ")");
  }
  *out = {type, p};
  const std::uint8_t* q = p;
  if (!skip(type, &q, end)) return fail(truncated);  // the value itself fits in the bytes
  return true;
}

bool MessageFields::number(const std::uint8_t* data, std::size_t size, const std::string& path, double* out,
                           std::string* why) const {
  Value v;
  if (!find(data, size, path, &v, why)) return false;
  const std::string& t = v.type;
  if (t == "float64")
    *out = as<double>(v.at);
  else if (t == "float32")
    *out = as<float>(v.at);
  else if (t == "int8")
    *out = as<std::int8_t>(v.at);
  else if (t == "uint8" || t == "byte" || t == "char" || t == "bool")
    *out = as<std::uint8_t>(v.at);
  else if (t == "int16")
    *out = as<std::int16_t>(v.at);
  else if (t == "uint16")
    *out = as<std::uint16_t>(v.at);
  else if (t == "int32")
    *out = as<std::int32_t>(v.at);
  else if (t == "uint32")
    *out = as<std::uint32_t>(v.at);
  else if (t == "int64")
    *out = as<std::int64_t>(v.at);
  else if (t == "uint64")
    *out = as<std::uint64_t>(v.at);
  else if (t == "time")
    *out = as<std::uint32_t>(v.at) + 1e-9 * as<std::uint32_t>(v.at + 4);
  else if (t == "duration")
    *out = as<std::int32_t>(v.at) + 1e-9 * as<std::int32_t>(v.at + 4);
  else {
    if (why) *why = "'" + path + "' is a " + t + ", not a number";
    return false;
  }
  return true;
}

bool MessageFields::text(const std::uint8_t* data, std::size_t size, const std::string& path, std::string* out,
                         std::string* why) const {
  Value v;
  if (!find(data, size, path, &v, why)) return false;
  if (v.type != "string") {
    if (why) *why = "'" + path + "' is a " + v.type + ", not a string";
    return false;
  }
  std::uint32_t n = 0;
  std::memcpy(&n, v.at, 4);
  out->assign(reinterpret_cast<const char*>(v.at + 4), n);
  return true;
}

}  // namespace ros_bag
}  // namespace uw_multislam
