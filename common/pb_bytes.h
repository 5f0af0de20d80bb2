/* pb_bytes: plain values to bytes and back, for state a program saves and reads again
 * itself (the mapper's checkpoint): native byte order, no padding, every read bounded.
 * C++ only, header only. ByteWriter appends to a vector it does not own; ByteReader reads
 * a buffer it does not own and sets ok = false (and returns zeros) past its end. */
#ifndef PB_BYTES_H
#define PB_BYTES_H

#include <stddef.h>
#include <stdint.h>
#include <cstring>
#include <string>
#include <vector>

struct ByteWriter {
    std::vector<uint8_t> *out;
    template <class T> void put(const T &v)
    {
        const uint8_t *b = (const uint8_t *)&v;
        out->insert(out->end(), b, b + sizeof v);
    }
    template <class T> void put_array(const T *v, size_t n)
    {
        put((uint64_t)n);
        const uint8_t *b = (const uint8_t *)v;
        out->insert(out->end(), b, b + n * sizeof(T));
    }
    void put_string(const std::string &s) { put_array(s.data(), s.size()); }
};

struct ByteReader {
    const uint8_t *p, *end;
    bool ok = true;
    template <class T> T get()
    {
        T v{};
        if ((size_t)(end - p) < sizeof v) { ok = false; return v; }
        std::memcpy(&v, p, sizeof v);
        p += sizeof v;
        return v;
    }
    /* an array put_array wrote, into *v (replaced) */
    template <class T> void get_array(std::vector<T> *v)
    {
        uint64_t n = get<uint64_t>();
        if (!ok || n > (uint64_t)(end - p) / sizeof(T)) { ok = false; v->clear(); return; }
        v->resize((size_t)n);
        if (n) std::memcpy(v->data(), p, (size_t)n * sizeof(T));   /* data() may be NULL when empty */
        p += n * sizeof(T);
    }
    std::string get_string()
    {
        std::vector<char> c;
        get_array(&c);
        return std::string(c.begin(), c.end());
    }
};

/* FNV-1a, 64 bits: a checksum of bytes (not for security). */
inline uint64_t pb_fnv1a64(const void *data, size_t n, uint64_t h = 1469598103934665603ull)
{
    const uint8_t *b = (const uint8_t *)data;
    for (size_t i = 0; i < n; i++) h = (h ^ b[i]) * 1099511628211ull;
    return h;
}

#endif
