// pointviz — what a reader of a file's data block throws when the data is not what its header
// (and so the reader's spec) says. The Python readers turn both into one-line errors naming the
// file.
#pragma once

#include <stdexcept>

namespace pointviz {

/// The data ends before what the spec asks for (rows, a grid, faces).
struct TruncatedData : std::runtime_error {
    using std::runtime_error::runtime_error;
};

/// A row that is not what the spec says: too few or too many values, a token that is not a
/// number, an index out of range. The message names the row (0-based, counted from the first
/// row of the block).
struct MalformedData : std::runtime_error {
    using std::runtime_error::runtime_error;
};

}  // namespace pointviz
