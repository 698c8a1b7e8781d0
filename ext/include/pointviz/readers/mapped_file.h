// pointviz — a read-only memory map of part of a file: the page cache read in place by the
// table and face readers, with neither a zero-filled buffer nor a copy.
#pragma once

#include <algorithm>
#include <cerrno>
#include <cstdint>
#include <cstring>
#include <stdexcept>
#include <string>

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include "pointviz/readers/data_errors.h"

namespace pointviz {

/// A read-only memory map of a file's bytes [offset, offset + length): the page cache is read in
/// place, with neither a zero-filled buffer nor a copy. (A file truncated by another process while
/// it is mapped would fault; files are not expected to change while they load.)
class MappedBytes {
  public:
    MappedBytes(const std::string &path, uint64_t offset, uint64_t limit) {
        int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
        if (fd < 0) throw std::runtime_error("cannot open " + path + ": " + std::strerror(errno));
        struct stat st;
        if (::fstat(fd, &st) != 0) {
            ::close(fd);
            throw std::runtime_error("cannot stat " + path + ": " + std::strerror(errno));
        }
        uint64_t end = uint64_t(st.st_size);
        if (end < offset) {
            ::close(fd);
            throw TruncatedData("the file ends at byte " + std::to_string(end) +
                                ", before its data starts at byte " + std::to_string(offset));
        }
        size_ = size_t(std::min(end - offset, limit));
        if (size_ > 0) {
            // map from the page holding `offset`
            const uint64_t page = uint64_t(::sysconf(_SC_PAGESIZE));
            const uint64_t start = offset / page * page;
            map_len_ = size_t(offset - start) + size_;
            map_ = ::mmap(nullptr, map_len_, PROT_READ, MAP_PRIVATE, fd, off_t(start));
            if (map_ == MAP_FAILED) {
                map_ = nullptr;
                ::close(fd);
                throw std::runtime_error("cannot map " + path + ": " + std::strerror(errno));
            }
            ::madvise(map_, map_len_, MADV_SEQUENTIAL | MADV_WILLNEED);
            data_ = static_cast<const char *>(map_) + (offset - start);
        }
        ::close(fd);
    }
    ~MappedBytes() {
        if (map_) ::munmap(map_, map_len_);
    }
    MappedBytes(const MappedBytes &) = delete;
    MappedBytes &operator=(const MappedBytes &) = delete;

    const char *data() const { return data_; }
    size_t size() const { return size_; }

  private:
    void *map_ = nullptr;
    size_t map_len_ = 0;
    const char *data_ = "";
    size_t size_ = 0;
};

}  // namespace pointviz
