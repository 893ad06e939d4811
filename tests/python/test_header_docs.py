"""python/tools/header_docs.py: the docstrings come from the headers' /// and ///< comments."""

import importlib.util
import pathlib

import pytest

TOOL = pathlib.Path(__file__).resolve().parents[2] / "python" / "tools" / "header_docs.py"
spec = importlib.util.spec_from_file_location("header_docs", TOOL)
header_docs = importlib.util.module_from_spec(spec)
spec.loader.exec_module(header_docs)

HEADER = r'''// A file comment
// on two lines.
#pragma once
#include <vector>

namespace perch2 {

/// A settings struct.
struct S {
  float a_m = 0.1f, b_m = 0.2f;  ///< two fields, one comment
  /// Preceding comment
  /// on two lines.
  int c = 1 << 20;
  float d =
      1e-6f;  ///< broken by clang-format
  float e = 0.5f;  ///< continued
                   ///< on the next line
  std::vector<std::pair<int, int>> pairs{{1, 2}};  ///< template commas
  /// A lambda initialiser.
  Other o = [] {
    Other x;
    x.v = 2;  ///< not a member of S
    return x;
  }();
  /// A method with a default argument.
  void f(int x, Other y = {}) const { use(x); }
 public:
  /// After an access specifier.
  explicit S(int q) : a_m(q) {}
};

enum class E : int {
  One,  ///< the first
  /// the second
  Two,
};

/// A free function.
template <class T>
inline T twice(T x) {
  return 2 * x;
}

}  // namespace perch2
'''


def test_extracts_fields_enums_functions_and_file_comment():
    docs, file_doc = header_docs.parse_header(HEADER)
    assert file_doc == "A file comment\non two lines."
    assert docs["S"] == "A settings struct."
    assert docs["S.a_m"] == docs["S.b_m"] == "two fields, one comment"
    assert docs["S.c"] == "Preceding comment\non two lines."
    assert docs["S.d"] == "broken by clang-format"
    assert docs["S.e"] == "continued\non the next line"
    assert docs["S.pairs"] == "template commas"
    assert docs["S.o"] == "A lambda initialiser."
    assert "S.v" not in docs and "S.x" not in docs
    assert docs["S.f"] == "A method with a default argument."
    assert docs["S.S"] == "After an access specifier."
    assert docs["E.One"] == "the first" and docs["E.Two"] == "the second"
    assert docs["twice"] == "A free function."


def test_writes_a_header_of_raw_strings(tmp_path):
    h = tmp_path / "x.hpp"
    h.write_text(HEADER.replace("two fields, one comment", 'quote " and )perch2doc" inside'))
    out = tmp_path / "docs.hpp"
    assert header_docs.main(["--out", str(out), "--root", str(tmp_path), str(h)]) == 0
    text = out.read_text()
    assert '{R"perch2doc(file:x.hpp)perch2doc"' in text
    assert 'quote " and )perch2doc" inside' in text and 'R"perch2doc_(' in text


@pytest.mark.parametrize("key", ["TabletopSettings.xy_step_m", "SixDofSettings.local", "KnnMethod.Grid",
                                 "SixDofEstimator.estimate", "file:perch2/search/sixdof.hpp"])
def test_real_headers_document_what_the_bindings_use(key):
    include = TOOL.parents[2] / "include"
    headers = sorted(include.rglob("*.hpp"))
    entries = header_docs.collect(headers, str(include))
    assert entries.get(key), key
