// Lowering the scheduling priority of the calling thread, for the helper
// threads that must not take CPU from a session's tracking thread on a
// small machine (the background mapper, a client's frame reader).
#pragma once

namespace twist {

// Sets the calling thread's nice value to `niceness` (Linux: a thread's nice
// value is its own; > 0 lowers the priority, 19 is the lowest). Nothing for
// niceness <= 0. Failing costs speed, not correctness: logged as a warning
// naming `what`, and false returned.
bool SetThisThreadNiceness(int niceness, const char* what);

// The calling thread's nice value.
int ThisThreadNiceness();

}  // namespace twist
