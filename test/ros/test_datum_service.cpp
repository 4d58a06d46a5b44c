// The back-end's datum rules (ros/datum_service.h): set_datum's checks and the datum in use at
// start-up, store over parameters.
#include <gtest/gtest.h>

#include <cmath>
#include <optional>
#include <string>
#include <vector>

#include "uw_multislam/core/export/geo_datum.h"
#include "uw_multislam/ros/datum_service.h"

namespace uw_multislam {
namespace ros_geo {
namespace {

using core::GeoOrigin;
using core::StatusCode;

bool has(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

TEST(DatumService, ARequestWithoutAHeadingIsEnu) {
  uw_multislam::SetDatum::Request r;
  r.latitude_deg = 43.1, r.longitude_deg = 5.9, r.altitude_m = 2.0, r.heading_deg = 30.0;
  EXPECT_TRUE(core::sameDatum(datumFromRequest(r), GeoOrigin{43.1, 5.9, 90.0, 2.0}));
  r.with_heading = true;
  EXPECT_TRUE(core::sameDatum(datumFromRequest(r), GeoOrigin{43.1, 5.9, 30.0, 2.0}));
}

TEST(DatumService, SetDatumSetsKeepsOrRefusesAsTheRulesSay) {
  const GeoOrigin a{43.1, 5.9, 30.0, 0.0}, b{43.2, 5.9, 90.0, 0.0};
  // None in use: set.
  core::Status st = checkSetDatum(std::nullopt, "", a, false, "utm");
  EXPECT_TRUE(st.ok() && st.message.empty()) << st.message;
  // The same one: nothing to do, said so.
  st = checkSetDatum(a, "set_datum", a, false, "utm");
  EXPECT_TRUE(st.ok()) << st.message;
  EXPECT_TRUE(has(st.message, "unchanged")) << st.message;
  // Another one: refused unless replace, naming the datum in use and its source.
  st = checkSetDatum(a, "~datum/* parameters", b, false, "utm");
  EXPECT_EQ(st.code, StatusCode::kAlreadyExists);
  EXPECT_TRUE(has(st.message, core::describeDatum(a)) && has(st.message, "~datum/* parameters") &&
              has(st.message, "replace: true"))
      << st.message;
  st = checkSetDatum(a, "~datum/* parameters", b, true, "utm");
  EXPECT_TRUE(st.ok() && st.message.empty()) << st.message;
  // Bad values, even with replace; a polar datum only with a UTM frame.
  for (const GeoOrigin& bad : {GeoOrigin{std::nan(""), 5.9, 90.0}, GeoOrigin{91.0, 5.9, 90.0},
                               GeoOrigin{43.0, 5.9, INFINITY}, GeoOrigin{85.0, 5.9, 90.0}}) {
    st = checkSetDatum(a, "set_datum", bad, true, "utm");
    EXPECT_EQ(st.code, StatusCode::kInvalidArgument) << core::datumText(bad);
    EXPECT_TRUE(has(st.message, "nothing changed")) << st.message;
  }
  EXPECT_TRUE(has(checkSetDatum(a, "", {85.0, 5.9, 90.0}, true, "utm").message, "utm_frame"));
  EXPECT_TRUE(checkSetDatum(a, "", {85.0, 5.9, 90.0}, true, "").ok());
}

TEST(DatumService, AtStartUpTheStoresDatumWinsOverTheParametersWithAWarning) {
  const GeoOrigin params{43.1, 5.9, 30.0, 0.0}, stored{43.2, 5.8, 90.0, 1.5};
  std::string source;
  std::vector<std::string> notes;
  std::optional<GeoOrigin> d = startDatum(params, std::nullopt, &source, &notes);
  ASSERT_TRUE(d);
  EXPECT_TRUE(core::sameDatum(*d, params));
  EXPECT_EQ(source, "~datum/* parameters");
  EXPECT_TRUE(notes.empty());
  EXPECT_FALSE(startDatum(std::nullopt, std::nullopt, &source, &notes));
  d = startDatum(params, core::datumText(stored), &source, &notes);
  ASSERT_TRUE(d);
  EXPECT_TRUE(core::sameDatum(*d, stored));
  EXPECT_TRUE(has(source, "set_datum")) << source;
  ASSERT_EQ(notes.size(), 1u);
  EXPECT_TRUE(has(notes[0], core::describeDatum(params)) && has(notes[0], "replace: true")) << notes[0];
  notes.clear();
  d = startDatum(std::nullopt, core::datumText(stored), &source, &notes);  // the same without parameters, no note
  ASSERT_TRUE(d);
  EXPECT_TRUE(notes.empty());
  EXPECT_THROW(startDatum(params, std::string("43.2,5.8"), &source, &notes), std::invalid_argument);
}

}  // namespace
}  // namespace ros_geo
}  // namespace uw_multislam
