#!/bin/sh
# The command line reads its numbers by one rule (src/cli/option_rules.h), checked on the built
# program: every number option of every command is added through it (its --help type name is
# INTEGER or NUMBER; an option added with CLI11's own conversion would say INT, UINT or FLOAT),
# `run --steps 010` runs ten steps (not eight, as octal), 99999999999999999999 is refused as out of
# range (not clamped to 2^63 - 1), and a limit is said as a rule, without a 310-digit bound.
# Usage: cli_numbers.sh CELLFORCE SOURCE_DIR (run in a scratch folder).
set -u
cellforce=$1
source_dir=$2
fail() { echo "FAILED: $*"; exit 1; }

for command in run forces evaluate bench; do
  "$cellforce" $command --help > help_$command.txt || fail "$command --help"
  if grep -nE ' (INT|UINT|FLOAT)([: =]|$)' help_$command.txt; then
    fail "$command has a number option read by CLI11's own conversion (octal, clamped)"
  fi
done

"$cellforce" run "$source_dir/systems/lj_droplet.toml" --steps 010 --backend cpu --quiet --overwrite \
  --thermo-file cli_steps.csv > /dev/null || fail "run --steps 010"
grep -q '^10,' cli_steps.csv || fail "run --steps 010 did not reach step 10: $(tail -n 1 cli_steps.csv)"
grep -q '^8,' cli_steps.csv && fail "run --steps 010 ran 8 steps (octal)"

expect_refused() {  # expect_refused TEXT ARGS...: the command fails and its message holds TEXT
  text=$1
  shift
  if "$cellforce" "$@" > out.txt 2>&1; then fail "$* was accepted"; fi
  grep -qF -- "$text" out.txt || fail "$*: expected '$text', got: $(head -c 300 out.txt)"
  [ "$(wc -c < out.txt)" -lt 400 ] || fail "$*: a message of $(wc -c < out.txt) bytes"
}
expect_refused "--steps: '99999999999999999999' is out of range" run --steps 99999999999999999999
expect_refused "--steps: '0x10' is not a decimal integer" bench --steps 0x10
expect_refused "--cells: must be > 0, got 0" evaluate --cells 0
expect_refused "--density: '1e400' is out of range" evaluate --density 1e400
expect_refused "--samples: must be between 2 and 100000, got 1" bench --samples 1
printf '1\n\nA 0 0 0\n' > one.xyz
expect_refused "--frame: '1.5' is not a decimal integer" forces one.xyz -o never.h5 --frame 1.5
expect_refused "--seed: '-1' is out of range" evaluate --seed -1
expect_refused "--skin: expected auto or a length >= 0: '1e400' is out of range" run --skin 1e400
expect_refused "scene: no such file: '" run "$(printf 'a%.0s' $(seq 1 5000)).toml"
echo "every number option reads decimal, refuses what its type cannot hold, and states its limits"
