// The voxel keys and hash tables of voxel.cpp (fmcwlog/kernels/voxel.py), shared with the fused
// kernels that thin on the way (deskew.cpp's deskew_source).
#pragma once

#include "common.hpp"

namespace fmcwlog {

// numpy's floor(v).astype(int64) on x86: a value outside int64's range, or NaN, becomes INT64_MIN.
// Truncation, one less for a negative non-integer: floor without a call into libm (the x86-64
// baseline has no rounding instruction).
inline int64_t floor_to_int64(double v) {
    if (!(v >= -9223372036854775808.0 && v < 9223372036854775808.0)) return std::numeric_limits<int64_t>::min();
    const int64_t i = int64_t(v);
    return double(i) > v ? i - 1 : i;
}

// voxel.voxel_keys of one point: (i << 32) ^ (j & 0xFFFFFFFF), i and j the voxel's int64 indices
inline uint64_t voxel_key(double x, double y, double size) {
    const uint64_t i = uint64_t(floor_to_int64(x / size)), j = uint64_t(floor_to_int64(y / size));
    return (i << 32) ^ (j & 0xFFFFFFFFull);
}

// The size of an open-addressing table for n keys: a power of two, at least 16 and twice n.
inline size_t table_capacity(size_t n) {
    size_t cap = 16;
    while (cap < 2 * n) cap <<= 1;
    return cap;
}

// An open-addressing set of keys (linear probing, a power-of-two table at least twice the points).
class KeySet {
  public:
    explicit KeySet(size_t n) {
        const size_t cap = table_capacity(n);
        keys_.assign(cap, 0);
        used_.assign(cap, 0);
        mask_ = cap - 1;
    }
    // Whether the key was new (it is in the set afterwards either way).
    bool insert(uint64_t key) {
        uint64_t h = key * 0x9E3779B97F4A7C15ull;
        size_t at = size_t(h ^ (h >> 29)) & mask_;
        while (used_[at]) {
            if (keys_[at] == key) return false;
            at = (at + 1) & mask_;
        }
        used_[at] = 1;
        keys_[at] = key;
        return true;
    }

  private:
    std::vector<uint64_t> keys_;
    std::vector<uint8_t> used_;
    size_t mask_ = 0;
};

// An open-addressing map from key to slot (the order of first appearance), as KeySet.
class KeySlots {
  public:
    explicit KeySlots(size_t n) {
        const size_t cap = table_capacity(n);
        keys_.assign(cap, 0);
        slot_.assign(cap, -1);
        mask_ = cap - 1;
    }
    // The key's slot, a new one (== size before the call) where the key is new.
    int64_t slot(uint64_t key) {
        uint64_t h = key * 0x9E3779B97F4A7C15ull;
        size_t at = size_t(h ^ (h >> 29)) & mask_;
        while (slot_[at] >= 0) {
            if (keys_[at] == key) return slot_[at];
            at = (at + 1) & mask_;
        }
        keys_[at] = key;
        slot_[at] = size_++;
        return slot_[at];
    }
    int64_t size() const { return size_; }

  private:
    std::vector<uint64_t> keys_;
    std::vector<int64_t> slot_;
    size_t mask_ = 0;
    int64_t size_ = 0;
};

// A new numpy (m, 2) float64 array owning a copy of xy's first m rows.
inline nb::ndarray<nb::numpy, double, nb::shape<-1, 2>> numpy_points(const double* xy, size_t m) {
    double* out = new double[2 * m + 1];
    std::copy(xy, xy + 2 * m, out);
    nb::capsule owner(out, [](void* d) noexcept { delete[] static_cast<double*>(d); });
    return nb::ndarray<nb::numpy, double, nb::shape<-1, 2>>(out, {m, 2}, owner);
}

// voxel.voxel_downsample's points for size > 0: the first point (interleaved x, y) of each voxel of
// p's n points, in the order given (np.unique's first index of each key, sorted).
inline std::vector<double> first_of_voxels(const double* p, size_t n, double size) {
    std::vector<double> kept;
    KeySet seen(n);
    kept.reserve(2 * n);
    for (size_t i = 0; i < n; ++i)
        if (seen.insert(voxel_key(p[2 * i], p[2 * i + 1], size))) {
            kept.push_back(p[2 * i]);
            kept.push_back(p[2 * i + 1]);
        }
    return kept;
}

// voxel.voxel_centroids_numpy for size > 0: each voxel's mean (interleaved x, y) of p's n points, in
// the order of its first point; the sums run in the order given (np.bincount's), then one division each.
inline std::vector<double> voxel_means(const double* p, size_t n, double size) {
    std::vector<double> sum;
    std::vector<int64_t> count;
    KeySlots slots(n);
    sum.reserve(2 * n);
    count.reserve(n);
    for (size_t i = 0; i < n; ++i) {
        const int64_t s = slots.slot(voxel_key(p[2 * i], p[2 * i + 1], size));
        if (s == int64_t(count.size())) {
            sum.push_back(0.0);
            sum.push_back(0.0);
            count.push_back(0);
        }
        sum[2 * size_t(s)] += p[2 * i];
        sum[2 * size_t(s) + 1] += p[2 * i + 1];
        ++count[size_t(s)];
    }
    for (size_t k = 0; k < count.size(); ++k) {
        sum[2 * k] /= double(count[k]);
        sum[2 * k + 1] /= double(count[k]);
    }
    return sum;
}

}  // namespace fmcwlog
