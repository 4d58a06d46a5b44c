#!/usr/bin/env bash
# Checks that every C++ file under src/ and include/ is formatted as the repository's .clang-format
# says (clang-format --dry-run -Werror; nothing is changed). Exit status 0 only when all are.
#
#   bash scripts/format_check.sh [--junit FILE] [--root DIR]
#
# --junit FILE also writes a JUnit result (one test case; its failure lists the files and the first
# differences), as scripts/test.sh's summary reads. --root DIR checks DIR/src and DIR/include with
# DIR/.clang-format (default: this repository). To fix: clang-format -i FILE...
set -uo pipefail
repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd -P)
junit=""
while [ $# -gt 0 ]; do
  case "$1" in
    --junit) junit=${2:?--junit needs a file}; shift 2 ;;
    --root) repo=$(cd "${2:?--root needs a directory}" && pwd -P) || exit 2; shift 2 ;;
    -h | --help) sed -n '2,9p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "format_check: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
done

xml_escape() { sed -e 's/&/\&amp;/g' -e 's/</\&lt;/g' -e 's/>/\&gt;/g' -e 's/"/\&quot;/g'; }

# $1: number of files checked, $2: failure message ("" when every file is formatted), stdin: details.
write_junit() {
  [ -n "$junit" ] || return 0
  mkdir -p "$(dirname "$junit")"
  {
    echo '<?xml version="1.0" encoding="UTF-8"?>'
    if [ -z "$2" ]; then
      echo "<testsuite name=\"clang_format\" tests=\"1\" failures=\"0\" errors=\"0\" time=\"$SECONDS\">"
      echo "<testcase classname=\"clang_format\" name=\"src_and_include_formatted\"/>"
    else
      echo "<testsuite name=\"clang_format\" tests=\"1\" failures=\"1\" errors=\"0\" time=\"$SECONDS\">"
      echo "<testcase classname=\"clang_format\" name=\"src_and_include_formatted\">"
      echo "<failure message=\"$(printf '%s' "$2" | xml_escape)\">$(xml_escape)</failure>"
      echo "</testcase>"
    fi
    echo "</testsuite>"
  } >"$junit"
}

if ! command -v clang-format >/dev/null 2>&1; then
  msg="clang-format is not installed (scripts/install_deps.sh installs it)"
  echo "format_check: $msg" >&2
  echo "$msg" | write_junit 0 "$msg"
  exit 1
fi
if [ ! -f "$repo/.clang-format" ]; then
  msg="no .clang-format in $repo"
  echo "format_check: $msg" >&2
  echo "$msg" | write_junit 0 "$msg"
  exit 1
fi

cd "$repo" || exit 1
mapfile -t files < <(find src include -type f \( -name '*.cpp' -o -name '*.cc' -o -name '*.h' -o -name '*.hpp' \) 2>/dev/null | sort)
if [ ${#files[@]} -eq 0 ]; then
  msg="no C++ file found under src/ and include/"
  echo "format_check: $msg" >&2
  echo "$msg" | write_junit 0 "$msg"
  exit 1
fi
# --style=file: the .clang-format at the repository root (found from each file's directory).
out=$(clang-format --style=file --dry-run -Werror "${files[@]}" 2>&1)
status=$?
version=$(clang-format --version)
if [ $status -eq 0 ]; then
  echo "format_check: ${#files[@]} files formatted as .clang-format says ($version)"
  : | write_junit "${#files[@]}" ""
  exit 0
fi
# clang-format reports "file:line:col: error: code should be clang-formatted [-Wclang-format-violations]".
mapfile -t bad < <(printf '%s\n' "$out" | sed -n 's/^\([^:]*\):[0-9]*:[0-9]*: error: .*clang-format-violations.*/\1/p' | sort -u)
places=$(printf '%s\n' "$out" | grep -c "clang-format-violations")
if [ ${#bad[@]} -eq 0 ]; then
  msg="clang-format failed (status $status)"
else
  msg="${#bad[@]} of ${#files[@]} files not formatted ($places places); fix with clang-format -i on the files listed"
fi
echo "format_check: $msg ($version)" >&2
{
  printf '%s\n' "${bad[@]}"
  echo "--- the first differences ($version):"
  printf '%s\n' "$out" | head -n 150
} >"${TMPDIR:-/tmp}/format_check.$$"
head -n 60 "${TMPDIR:-/tmp}/format_check.$$" >&2
write_junit "${#files[@]}" "$msg" <"${TMPDIR:-/tmp}/format_check.$$"
rm -f "${TMPDIR:-/tmp}/format_check.$$"
exit 1
