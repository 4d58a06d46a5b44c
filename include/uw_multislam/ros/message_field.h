// One field of a serialized ROS message of any type, read by its path ("altitude",
// "pose.pose.position.z", "ranges[2]", "header.frame_id") from the message definition a bag stores
// with each connection (the .msg text with its dependencies, as rosbag writes it), without the
// message's C++ type: what offline_slam --bag needs to take a DVL driver's own message as altitude,
// as the launch files' dvl relay (scripts/dvl_altitude.py) does live with a Python expression.
// Never throws: a path the type does not have, or bytes shorter than the type says, give false
// with a one-line reason (the first naming the fields the type has).
#pragma once

#include <cstddef>
#include <cstdint>
#include <map>
#include <string>
#include <vector>

namespace uw_multislam {
namespace ros_bag {

class MessageFields {
 public:
  /// `datatype` ("pkg/Type") and its full definition (rosbag's message_definition). Check ok().
  MessageFields(const std::string& datatype, const std::string& definition);
  /// False (why()) for a definition that cannot be parsed.
  bool ok() const { return why_.empty(); }
  const std::string& why() const { return why_; }
  /// The number at `path` in the serialized message (numbers of any width, bool, time and
  /// duration as seconds). False with `why` for a path the type lacks or that is not a number.
  bool number(const std::uint8_t* data, std::size_t size, const std::string& path, double* out,
              std::string* why = nullptr) const;
  /// The string at `path` (e.g. header.frame_id).
  bool text(const std::uint8_t* data, std::size_t size, const std::string& path, std::string* out,
            std::string* why = nullptr) const;
  /// Whether the type's first field is a std_msgs/Header named header (its stamp and frame_id).
  bool hasHeader() const;

 private:
  struct Field {
    std::string type;  // primitive, or a full message name
    std::string name;
    bool array = false;
    long fixed = -1;  // T[N]: N; T[]: -1
  };
  struct Value {
    std::string type;
    const std::uint8_t* at = nullptr;
  };
  bool find(const std::uint8_t* data, std::size_t size, const std::string& path, Value* out, std::string* why) const;
  // Moves `*p` past one value of `type`; false when the bytes end first.
  bool skip(const std::string& type, const std::uint8_t** p, const std::uint8_t* end) const;
  bool skipMany(const std::string& type, std::uint32_t n, const std::uint8_t** p, const std::uint8_t* end) const;
  // The fewest bytes a value of `type` takes (variable arrays and strings: their length).
  std::size_t minBytes(const std::string& type) const;
  std::string fieldList(const std::string& type) const;

  std::string main_;
  std::map<std::string, std::vector<Field>> types_;
  std::string why_;
};

}  // namespace ros_bag
}  // namespace uw_multislam
