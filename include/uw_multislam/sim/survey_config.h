// Survey specs as YAML (the make_survey tool's --config and --dump-config). Every field of
// SurveySpec has a key; unknown keys are errors (a typo must not silently fall back to a
// default). A file may start from a built-in preset ("preset: demo") and override it; a
// `sessions` list replaces the preset's sessions, each entry starting from the defaults.
#pragma once

#include <string>

#include "uw_multislam/sim/survey_generator.h"

namespace uw_multislam {
namespace core {

/// Parses a survey spec; relative mosaic paths are taken relative to `base_dir`. Throws
/// std::invalid_argument with the key at fault.
SurveySpec surveyFromYaml(const std::string& yaml_text, const std::string& base_dir = ".");
/// Reads a YAML file (throws DatasetError when it cannot be read, std::invalid_argument when bad).
SurveySpec loadSurveyYaml(const std::string& path);
/// The full spec as YAML, every key present; surveyFromYaml(surveyToYaml(s)) == s.
std::string surveyToYaml(const SurveySpec& spec);

}  // namespace core
}  // namespace uw_multislam
