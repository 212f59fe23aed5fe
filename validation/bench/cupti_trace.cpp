// A timeline of a CUDA program's GPU operations and runtime API calls, through CUPTI's activity
// records, for machines without Nsight Systems: loaded by the CUDA driver as an injection library
// (CUDA_INJECTION64_PATH=/path/libcellforce-cupti-trace.so), it writes one CSV line per record to
// the file CF_TRACE_OUT names, at the program's exit:
//   kind,start_ns,end_ns,correlation,name
// with kind K (kernel), C (memcpy), S (memset) or R (runtime API call), times on CUPTI's clock (the
// same for the device's operations and the host's calls) and a GPU operation's correlation the
// same as the runtime call that launched it. validation/timeline_gaps.py reads it.
#include <cupti.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <mutex>

namespace {

std::FILE* out = nullptr;
std::mutex out_mutex;
constexpr std::size_t kBufferBytes = std::size_t(8) << 20;

void CUPTIAPI buffer_requested(uint8_t** buffer, std::size_t* size, std::size_t* max_records) {
  *buffer = static_cast<uint8_t*>(std::aligned_alloc(8, kBufferBytes));
  *size = *buffer ? kBufferBytes : 0;
  *max_records = 0;  // as many as fit
}

void CUPTIAPI buffer_completed(CUcontext, uint32_t, uint8_t* buffer, std::size_t, std::size_t valid) {
  std::lock_guard<std::mutex> lock(out_mutex);
  CUpti_Activity* record = nullptr;
  while (out && cuptiActivityGetNextRecord(buffer, valid, &record) == CUPTI_SUCCESS) {
    switch (record->kind) {
      case CUPTI_ACTIVITY_KIND_CONCURRENT_KERNEL:
      case CUPTI_ACTIVITY_KIND_KERNEL: {
        const auto* k = reinterpret_cast<const CUpti_ActivityKernel10*>(record);
        std::fprintf(out, "K,%llu,%llu,%u,\"%s\"\n", (unsigned long long)k->start, (unsigned long long)k->end,
                     k->correlationId, k->name ? k->name : "?");
        break;
      }
      case CUPTI_ACTIVITY_KIND_MEMCPY: {
        const auto* m = reinterpret_cast<const CUpti_ActivityMemcpy6*>(record);
        std::fprintf(out, "C,%llu,%llu,%u,memcpy %u bytes %llu\n", (unsigned long long)m->start,
                     (unsigned long long)m->end, m->correlationId, unsigned(m->copyKind),
                     (unsigned long long)m->bytes);
        break;
      }
      case CUPTI_ACTIVITY_KIND_MEMSET: {
        const auto* m = reinterpret_cast<const CUpti_ActivityMemset4*>(record);
        std::fprintf(out, "S,%llu,%llu,%u,memset %llu\n", (unsigned long long)m->start, (unsigned long long)m->end,
                     m->correlationId, (unsigned long long)m->bytes);
        break;
      }
      case CUPTI_ACTIVITY_KIND_RUNTIME: {
        const auto* a = reinterpret_cast<const CUpti_ActivityAPI*>(record);
        const char* name = nullptr;
        cuptiGetCallbackName(CUPTI_CB_DOMAIN_RUNTIME_API, a->cbid, &name);
        std::fprintf(out, "R,%llu,%llu,%u,%s\n", (unsigned long long)a->start, (unsigned long long)a->end,
                     a->correlationId, name ? name : "?");
        break;
      }
      default:
        break;
    }
  }
  std::size_t dropped = 0;
  cuptiActivityGetNumDroppedRecords(nullptr, 0, &dropped);
  if (dropped && out) std::fprintf(out, "D,0,0,0,dropped %zu\n", dropped);
  std::free(buffer);
}

void finish() {
  cuptiActivityFlushAll(1);
  std::lock_guard<std::mutex> lock(out_mutex);
  if (out) std::fclose(out);
  out = nullptr;
}

}  // namespace

extern "C" int InitializeInjection(void) {
  const char* path = std::getenv("CF_TRACE_OUT");
  out = std::fopen(path ? path : "cupti_trace.csv", "w");
  if (!out) return 0;
  if (cuptiActivityRegisterCallbacks(buffer_requested, buffer_completed) != CUPTI_SUCCESS) return 0;
  for (CUpti_ActivityKind kind : {CUPTI_ACTIVITY_KIND_CONCURRENT_KERNEL, CUPTI_ACTIVITY_KIND_MEMCPY,
                                  CUPTI_ACTIVITY_KIND_MEMSET, CUPTI_ACTIVITY_KIND_RUNTIME})
    cuptiActivityEnable(kind);
  std::atexit(finish);
  return 1;
}
