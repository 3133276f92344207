#include "slam/common/thread_priority.h"

#include <glog/logging.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

namespace twist {
namespace {

id_t ThisThreadId() { return static_cast<id_t>(syscall(SYS_gettid)); }

}  // namespace

bool SetThisThreadNiceness(int niceness, const char* what) {
  if (niceness <= 0) return true;
  if (setpriority(PRIO_PROCESS, ThisThreadId(), niceness) != 0) {
    PLOG(WARNING) << what << ": setpriority(" << niceness << ")";
    return false;
  }
  return true;
}

int ThisThreadNiceness() { return getpriority(PRIO_PROCESS, ThisThreadId()); }

}  // namespace twist
