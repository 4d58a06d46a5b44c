#include "cli.h"

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>

namespace uw_multislam::tools {

namespace {

class FlagValue : public po::typed_value<bool> {
 public:
  explicit FlagValue(bool* on) : po::typed_value<bool>(on) { zero_tokens(); }
  // No first-occurrence check: --quiet --quiet is --quiet.
  void xparse(boost::any& store, const std::vector<std::string>& /*tokens*/) const override { store = true; }
};

// The one-line reason for a command line boost::program_options refused.
std::string reason(const po::error& e) {
  if (const auto* bad = dynamic_cast<const BadValue*>(&e)) return bad->what();
  if (const auto* unknown = dynamic_cast<const po::unknown_option*>(&e))
    return "unknown argument '" + unknown->get_option_name() + "'";
  if (const auto* twice = dynamic_cast<const po::multiple_occurrences*>(&e))
    return twice->get_option_name() + " given more than once";
  if (const auto* value = dynamic_cast<const po::invalid_option_value*>(&e)) {
    po::invalid_option_value worded(*value);
    worded.m_error_template = "bad %canonical_option% '%value%'";
    return worded.what();
  }
  if (const auto* syntax = dynamic_cast<const po::invalid_command_line_syntax*>(&e)) {
    switch (syntax->kind()) {
      case po::invalid_command_line_syntax::missing_parameter:
      case po::invalid_command_line_syntax::empty_adjacent_parameter:
        return syntax->get_option_name() + " needs a value";
      case po::invalid_command_line_syntax::extra_parameter:
        return syntax->get_option_name() + " takes no value";
      default:
        break;
    }
  }
  return e.what();
}

}  // namespace

po::typed_value<bool>* flag(bool* on) { return new FlagValue(on); }

bool parseInteger(const std::string& text, long long lo, long long hi, long long* value) {
  if (text.empty() || !(text[0] == '-' || (text[0] >= '0' && text[0] <= '9'))) return false;  // strtoll skips spaces
  char* end = nullptr;
  errno = 0;
  const long long v = std::strtoll(text.c_str(), &end, 10);
  if (*end != '\0' || errno == ERANGE || v < lo || v > hi) return false;
  *value = v;
  return true;
}

bool parseNumber(const std::string& text, double* value) {
  char* end = nullptr;
  const double v = std::strtod(text.c_str(), &end);
  if (text.empty() || *end != '\0' || !std::isfinite(v)) return false;
  *value = v;
  return true;
}

CommandLine::CommandLine(std::string tool, std::string usage) : tool_(std::move(tool)), usage_(std::move(usage)) {}

std::optional<int> CommandLine::parse(int argc, const char* const argv[]) {
  bool help = false;
  std::vector<std::string> arguments;  // not options
  po::options_description all;
  all.add(options_).add_options()("help,h", flag(&help))("arguments__", po::value(&arguments));
  po::positional_options_description positional;
  positional.add("arguments__", -1);
  try {
    // Whole names only: with guessing, --ses would be --session, and a new option starting the same way
    // would change what an old command line means.
    po::store(po::command_line_parser(argc, argv)
                  .options(all)
                  .positional(positional)
                  .style(po::command_line_style::unix_style ^ po::command_line_style::allow_guessing)
                  .run(),
              values_);
    po::notify(values_);
  } catch (const po::error& e) {
    return bad(reason(e));
  }
  if (help) {
    std::puts(usage_.c_str());
    return 0;
  }
  if (!positional_ && !arguments.empty()) return bad("unknown argument '" + arguments.front() + "'");
  if (positional_) *positional_ = std::move(arguments);
  return std::nullopt;
}

int CommandLine::bad(const std::string& why) const {
  std::fprintf(stderr, "%s: %s (see --help)\n", tool_.c_str(), why.c_str());
  return kBadArguments;
}

}  // namespace uw_multislam::tools
