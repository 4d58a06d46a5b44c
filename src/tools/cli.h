// The command line of every C++ tool (boost::program_options), with one set of rules:
//  - -h / --help prints the tool's usage text on stdout; exit status 0;
//  - an unknown option, an option without its value, a bad value, an option of one value given twice, or an
//    argument the tool does not take: one line "<tool>: <reason> (see --help)" on stderr; exit status 2;
//  - a flag may be given twice (it means the same); an option declared with a vector collects every occurrence
//    (--session A --session B), with multitoken() also several values after one name (--images A B C);
//  - option names are matched whole (no abbreviation), and --name=value works as --name value.
#pragma once

#include <boost/program_options.hpp>

#include <functional>
#include <limits>
#include <optional>
#include <string>
#include <vector>

namespace uw_multislam::tools {

namespace po = boost::program_options;

/// Exit status for a command line the tool refuses.
constexpr int kBadArguments = 2;

/// A value refused by a checked option: `message` may use %canonical_option% (the option as written, e.g.
/// --threads) and %value% (the text given).
class BadValue : public po::error_with_option_name {
 public:
  BadValue(const std::string& message, const std::string& value) : po::error_with_option_name(message) {
    set_substitute("value", value);
  }
};

/// Converts an option's text: "" when it is good (and *value set), else the message refusing it (placeholders
/// as in BadValue).
template <typename T>
using ParseValue = std::function<std::string(const std::string& text, T* value)>;

namespace detail {

template <typename T>
struct NonDeduced {  // T deduced from the target alone: a lambda or function converts to ParseValue<T>
  using type = T;
};

template <typename T>
class CheckedValue : public po::typed_value<std::string> {
 public:
  CheckedValue(T* target, ParseValue<T> parse)
      : po::typed_value<std::string>(nullptr), target_(target), parse_(std::move(parse)) {}
  void xparse(boost::any& store, const std::vector<std::string>& tokens) const override {
    po::validators::check_first_occurrence(store);  // an option of one value, given twice: refused
    const std::string& text = po::validators::get_single_string(tokens);
    const std::string why = parse_(text, target_);
    if (!why.empty()) throw BadValue(why, text);
    store = text;
  }

 private:
  T* target_;
  ParseValue<T> parse_;
};

template <typename T>
class CheckedEach : public po::typed_value<std::vector<std::string>> {
 public:
  CheckedEach(std::vector<T>* targets, ParseValue<T> parse)
      : po::typed_value<std::vector<std::string>>(nullptr), targets_(targets), parse_(std::move(parse)) {}
  void xparse(boost::any& store, const std::vector<std::string>& tokens) const override {
    if (store.empty()) store = std::vector<std::string>();
    for (const std::string& text : tokens) {
      T value{};
      const std::string why = parse_(text, &value);
      if (!why.empty()) throw BadValue(why, text);
      targets_->push_back(std::move(value));
      boost::any_cast<std::vector<std::string>&>(store).push_back(text);
    }
  }

 private:
  std::vector<T>* targets_;
  ParseValue<T> parse_;
};

}  // namespace detail

/// An option of one value that `parse` converts into *target (given twice: refused).
template <typename T>
po::typed_value<std::string>* checked(T* target, typename detail::NonDeduced<ParseValue<T>>::type parse) {
  return new detail::CheckedValue<T>(target, std::move(parse));
}

/// An option that may be repeated, each value converted by `parse` and appended to *targets in order.
template <typename T>
po::typed_value<std::vector<std::string>>* checkedEach(std::vector<T>* targets,
                                                       typename detail::NonDeduced<ParseValue<T>>::type parse) {
  return new detail::CheckedEach<T>(targets, std::move(parse));
}

/// A flag (no value): sets *on; given twice, it means the same.
po::typed_value<bool>* flag(bool* on);

/// The whole text a base-10 integer in [lo, hi] (no sign beyond a leading '-', no space, no trailing text).
bool parseInteger(const std::string& text, long long lo, long long hi, long long* value);

/// The whole text a finite number (strtod's syntax).
bool parseNumber(const std::string& text, double* value);

/// An integer option in [lo, hi]; refused as "bad --opt 'text'", followed by ": <takes>" when given.
template <typename T>
po::typed_value<std::string>* integer(T* target, long long lo, long long hi, const std::string& takes = "") {
  return checked<T>(target, [lo, hi, takes](const std::string& text, T* value) -> std::string {
    long long v = 0;
    if (!parseInteger(text, lo, hi, &v))
      return "bad %canonical_option% '%value%'" + (takes.empty() ? "" : ": " + takes);
    *value = static_cast<T>(v);
    return "";
  });
}

/// An integer option, any value of T.
template <typename T>
po::typed_value<std::string>* integer(T* target) {
  return integer(target, std::numeric_limits<T>::min(), std::numeric_limits<T>::max());
}

/// A tool's command line: declare its options with add() as with boost::program_options, then parse().
class CommandLine {
 public:
  /// `tool`: the name that starts every message; `usage`: what --help prints.
  CommandLine(std::string tool, std::string usage);

  po::options_description_easy_init add() { return options_.add_options(); }

  /// The arguments that are not options, in order (without this call, such an argument is refused).
  void positional(std::vector<std::string>* arguments) { positional_ = arguments; }

  /// Parses argv into the declared targets. std::nullopt: parsed, go on; else the exit status to return now
  /// (0 after --help; kBadArguments after the one-line message).
  std::optional<int> parse(int argc, const char* const argv[]);

  /// Whether the option `name` was on the command line (after parse()).
  bool given(const std::string& name) const { return values_.count(name) > 0; }

  /// "<tool>: <why> (see --help)" on stderr; returns kBadArguments.
  int bad(const std::string& why) const;

 private:
  std::string tool_, usage_;
  po::options_description options_;
  po::variables_map values_;
  std::vector<std::string>* positional_ = nullptr;
};

}  // namespace uw_multislam::tools
