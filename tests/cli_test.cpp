// The command line's numbers (cli/option_rules.h): every integer option reads decimal digits only
// and refuses a value beyond its type, every real option refuses a value beyond a double's range
// as out of range, and a limit is stated as a rule. The options are built as main.cpp builds them
// and parsed from argument lists.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cstdint>
#include <string>
#include <vector>

#include "cli/option_rules.h"
#include "core/option_table.h"

namespace {

using namespace cellforce;
using ::testing::HasSubstr;
using ::testing::Not;

// Parses `args` (after the program name) with `app`; returns CLI11's message, "" on success.
std::string parse(CLI::App& app, std::vector<std::string> args) {
  std::vector<std::string> argv = {"cellforce"};
  argv.insert(argv.end(), args.begin(), args.end());
  std::vector<char*> pointers;
  for (std::string& a : argv) pointers.push_back(a.data());
  try {
    app.parse(int(pointers.size()), pointers.data());
  } catch (const CLI::ParseError& e) {
    return e.what();
  }
  return {};
}

TEST(CliNumbers, IntegersAreDecimal) {
  for (const auto& [text, value] : std::vector<std::pair<std::string, int64_t>>{
           {"010", 10}, {"08", 8}, {"0", 0}, {"+7", 7}, {"9223372036854775807", INT64_MAX}}) {
    CLI::App app;
    int64_t steps = -1;
    cli::add_number(&app, "--steps", steps, "steps", cli::kNonNegative);
    EXPECT_EQ(parse(app, {"--steps", text}), "") << text;
    EXPECT_EQ(steps, value) << text;
  }
}

TEST(CliNumbers, IntegersBeyondTheTypeAreRefused) {
  {
    CLI::App app;
    int64_t steps = -1;
    cli::add_number(&app, "--steps", steps, "steps", cli::kNonNegative);
    const std::string message = parse(app, {"--steps", "99999999999999999999"});
    EXPECT_THAT(message, HasSubstr("--steps: '99999999999999999999' is out of range"));
    EXPECT_THAT(message, HasSubstr("9223372036854775807"));
    EXPECT_EQ(steps, -1);  // not clamped to 2^63 - 1
  }
  {
    CLI::App app;
    int cells = 5;
    cli::add_number(&app, "--cells", cells, "cells", cli::kPositive);
    EXPECT_THAT(parse(app, {"--cells", "4294967301"}),
                HasSubstr("'4294967301' is out of range (-2147483648 .. 2147483647)"));
    EXPECT_EQ(cells, 5);  // not wrapped to 5 either
  }
  {
    CLI::App app;
    uint64_t seed = 3;
    cli::add_number(&app, "--seed", seed, "seed");
    EXPECT_THAT(parse(app, {"--seed", "-1"}), HasSubstr("'-1' is out of range (0 .. 18446744073709551615)"));
    EXPECT_EQ(seed, 3u);
  }
}

TEST(CliNumbers, OtherBasesAndFractionsAreNotIntegers) {
  for (const std::string text : {"0x10", "1e3", "2.0", "", "-", "12abc", " 5", "0b1"}) {
    CLI::App app;
    int repeats = 1;
    cli::add_number(&app, "--repeats", repeats, "repeats", cli::kPositive);
    EXPECT_THAT(parse(app, {"--repeats", text}), HasSubstr("is not a decimal integer")) << text;
    EXPECT_EQ(repeats, 1);
  }
}

TEST(CliNumbers, LimitsAreSaidAsARule) {
  CLI::App app;
  int cells = 1, samples = 10;
  double density = 1, jitter = 0;
  cli::add_number(&app, "--cells", cells, "", cli::kPositive);
  cli::add_number(&app, "--density", density, "", cli::kPositive);
  cli::add_number(&app, "--jitter", jitter, "", cli::kNonNegative);
  cli::add_number(&app, "--samples", samples, "", cli::between(2, 100000));
  // No 310-digit bound, no "0 not in range 0.000000 ...".
  EXPECT_EQ(parse(app, {"--cells", "0"}), "--cells: must be > 0, got 0");
  EXPECT_EQ(parse(app, {"--density", "-0.5"}), "--density: must be > 0, got -0.5");
  EXPECT_EQ(parse(app, {"--jitter", "-1e-300"}), "--jitter: must be >= 0, got -1e-300");
  EXPECT_EQ(parse(app, {"--samples", "1"}), "--samples: must be between 2 and 100000, got 1");
  EXPECT_EQ(parse(app, {"--samples", "100000"}), "");
  EXPECT_EQ(samples, 100000);
}

TEST(CliNumbers, RealsOutOfRangeAreNotCalledNotANumber) {
  CLI::App app;
  double density = 1;
  cli::add_number(&app, "--density", density, "", cli::kPositive);
  const std::string big = parse(app, {"--density", "1e400"});
  EXPECT_THAT(big, HasSubstr("--density: '1e400' is out of range"));
  EXPECT_THAT(big, Not(HasSubstr("not a number")));
  EXPECT_THAT(parse(app, {"--density", "abc"}), HasSubstr("'abc' is not a number"));
  EXPECT_THAT(parse(app, {"--density", "inf"}), HasSubstr("must be a finite number, got 'inf'"));
  EXPECT_THAT(parse(app, {"--density", "nan"}), HasSubstr("must be a finite number, got 'nan'"));
  // Below the smallest double: the nearest value, as strtod and Python read it (then the rule).
  EXPECT_EQ(parse(app, {"--density", "1e-400"}), "--density: must be > 0, got 0");
}

TEST(CliNumbers, RealsReadExactly) {
  // Values whose decimal text, rounded first to long double (CLI11's strtold) and then to double,
  // could land on the wrong neighbour: the transform hands CLI11 the double itself.
  for (const double x : {0.8442, 0.1 + 0.2, 2.5, 1e-300, 1.7976931348623157e308, 5e-324, 0.30000000000000004,
                         1.0000000000000002}) {
    CLI::App app;
    double value = -1;
    cli::add_number(&app, "--value", value, "");
    EXPECT_EQ(parse(app, {"--value", format_number(x)}), "");
    EXPECT_EQ(value, x) << format_number(x);
  }
  CLI::App app;
  std::vector<double> sizes;
  cli::add_number(&app, "--sizes", sizes, "", cli::Limits{1.0});
  EXPECT_EQ(parse(app, {"--sizes", "32000", "2.56e5"}), "");
  EXPECT_EQ(sizes, (std::vector<double>{32000, 256000}));
  EXPECT_EQ(parse(app, {"--sizes", "32000", "0"}), "--sizes: must be >= 1, got 0");
}

TEST(CliNames, NamesInAnyCaseAndEscapedWhenRefused) {
  CLI::App app;
  std::string backend;
  app.add_option("--backend", backend, "")->transform(cli::name_in(option_spec(OptionId::kBackend).names));
  EXPECT_EQ(parse(app, {"--backend", "CUDA"}), "");
  EXPECT_EQ(backend, "cuda");
  EXPECT_EQ(parse(app, {"--backend", std::string("gp\x01u")}), "--backend: 'gp\\x01u' is not one of auto, cpu, cuda");
}

TEST(CliFiles, AMissingFileIsNamedShortAndEscaped) {
  CLI::App app;
  std::string scene;
  app.add_option("scene", scene, "")->check(cli::existing_file());
  const std::string long_name(100000, 'a');
  const std::string message = parse(app, {long_name + ".toml"});
  EXPECT_THAT(message, HasSubstr("no such file: 'aaaa"));
  EXPECT_THAT(message, HasSubstr("... (100005 bytes)"));
  EXPECT_LT(message.size(), 400u);
  EXPECT_THAT(parse(app, {"/"}), HasSubstr("/ is a folder, not a file"));
  EXPECT_THAT(parse(app, {std::string("no\nsuch.toml")}), HasSubstr("no such file: 'no\\nsuch.toml'"));
}

}  // namespace
