/* What the shared library exports: the API and nothing of the engine underneath (it is built
 * with hidden visibility; these names are made visible). Usable from C and C++. */
#ifndef CELLFORCE_EXPORT_HPP
#define CELLFORCE_EXPORT_HPP

#if defined(__GNUC__) || defined(__clang__)
#define CELLFORCE_API __attribute__((visibility("default")))
#else
#define CELLFORCE_API
#endif

#endif
