#include "server/service.h"

#include <glog/logging.h>

#include <atomic>
#include <chrono>
#include <thread>

#include "absl/strings/str_cat.h"
#include "server/status_util.h"

namespace twist::server {
namespace {

double MsSince(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t).count();
}

void FillError(int64_t index,
               int64_t timestamp_ns,
               const absl::Status& status,
               pb::StreamResponse* out) {
  pb::FrameError* e = out->mutable_error();
  e->set_index(index);
  e->set_timestamp_ns(timestamp_ns);
  e->set_code(static_cast<int>(status.code()));
  e->set_message(std::string(status.message()));
}

// The stream's worker: pops frames, runs the engine, writes the answers.
// Returns false when a write failed (the client is gone).
bool RunWorker(Session* session,
               FrameQueue* queue,
               grpc::ServerReaderWriter<pb::StreamResponse, pb::StreamRequest>* stream,
               Metrics* metrics) {
  std::vector<int64_t> dropped;
  int64_t dropped_count = 0;
  int64_t dropped_total = 0;
  while (true) {
    std::optional<QueueItem> item = queue->Pop(&dropped, &dropped_count);
    if (dropped_count > 0) {
      session->RecordDropped(dropped_count);
      if (metrics) metrics->FramesDropped(dropped_count);
      dropped_total += dropped_count;
      pb::StreamResponse response;
      pb::FramesDropped* d = response.mutable_dropped();
      for (int64_t i : dropped) d->add_indices(i);
      d->set_total_dropped(session->Info().frames_dropped());
      d->set_reason(absl::StrCat(
          dropped_count,
          " frame(s) dropped: input queue full (OVERFLOW_POLICY_DROP_OLDEST, capacity ",
          queue->capacity(),
          ")"));
      if (item) {
        if (!stream->Write(response)) return false;
      } else {
        stream->Write(response);  // best effort at the end
      }
    }
    if (!item) return true;
    pb::StreamResponse response;
    if (!item->error.ok()) {
      session->RecordRejected();
      if (metrics) metrics->FrameRejected();
      FillError(item->index, item->timestamp_ns, item->error, &response);
      if (!stream->Write(response)) return false;
      continue;
    }
    const double queue_ms = MsSince(item->enqueued);
    double engine_ms = 0.0;
    absl::StatusOr<FrameResult> result = session->Process(item->frame, &engine_ms);
    if (!result.ok()) {
      if (metrics) metrics->FrameRejected();
      FillError(item->index, item->timestamp_ns, result.status(), &response);
      if (!stream->Write(response)) return false;
      continue;
    }
    pb::FrameUpdate* update = response.mutable_update();
    ToProto(*result, update);
    // The engine echoes the frame's index and timestamp; make sure the wire
    // carries the client's values even if an engine does not.
    update->set_index(item->index);
    update->set_timestamp_ns(item->timestamp_ns);
    pb::StageTiming* decode = update->add_timings();
    decode->set_stage("decode");
    decode->set_ms(item->decode_ms);
    pb::StageTiming* queued = update->add_timings();
    queued->set_stage("queue");
    queued->set_ms(queue_ms);
    pb::StageTiming* engine = update->add_timings();
    engine->set_stage("engine");
    engine->set_ms(engine_ms);
    update->set_queue_depth(queue->size());
    if (metrics) metrics->FrameProcessed(engine_ms, item->decode_ms + queue_ms + engine_ms);
    session->RememberUpdate(*update);
    if (!stream->Write(response)) return false;
  }
}

}  // namespace

SlamServiceImpl::SlamServiceImpl(SessionManager* manager,
                                 Metrics* metrics,
                                 const TokenAuthenticator* auth,
                                 ServiceInfo info)
    : manager_(manager), metrics_(metrics), auth_(auth), info_(std::move(info)) {}

grpc::Status SlamServiceImpl::CreateSession(grpc::ServerContext* context,
                                            const pb::CreateSessionRequest* request,
                                            pb::CreateSessionResponse* response) {
  absl::StatusOr<std::string> principal = auth_->Authenticate(*context);
  if (!principal.ok()) return ToGrpcStatus(principal.status());
  absl::StatusOr<std::shared_ptr<Session>> session = manager_->Create(*request, *principal);
  if (!session.ok()) return ToGrpcStatus(session.status());
  response->set_session_id((*session)->id());
  response->set_resume_token((*session)->resume_token());
  ToProto((*session)->camera(), response->mutable_effective_calibration());
  *response->mutable_session() = (*session)->Info();
  return grpc::Status::OK;
}

grpc::Status SlamServiceImpl::Stream(
    grpc::ServerContext* context,
    grpc::ServerReaderWriter<pb::StreamResponse, pb::StreamRequest>* stream) {
  absl::StatusOr<std::string> principal = auth_->Authenticate(*context);
  if (!principal.ok()) return ToGrpcStatus(principal.status());
  if (!manager_->accepting()) {
    return grpc::Status(grpc::StatusCode::UNAVAILABLE,
                        "server is shutting down; resume the session later");
  }
  pb::StreamRequest request;
  if (!stream->Read(&request)) return grpc::Status::OK;  // client left without binding
  if (!request.has_bind()) {
    return grpc::Status(
        grpc::StatusCode::FAILED_PRECONDITION,
        "the first Stream message must be a BindStream (a frame arrived before binding)");
  }
  absl::StatusOr<std::shared_ptr<Session>> found =
      manager_->Get(request.bind().session_id(), *principal);
  if (!found.ok()) return ToGrpcStatus(found.status());
  std::shared_ptr<Session> session = std::move(*found);

  FrameQueue queue(session->policy().queue_capacity(),
                   session->policy().overflow() == pb::OVERFLOW_POLICY_DROP_OLDEST);
  StreamHandle handle;
  handle.context = context;
  handle.queue = &queue;
  if (absl::Status s = session->Bind(&handle, manager_->options().takeover_wait); !s.ok()) {
    return ToGrpcStatus(s);
  }
  if (metrics_) metrics_->StreamOpened();
  VLOG(1) << "session " << session->id() << ": stream bound";
  {
    std::vector<pb::FrameUpdate> replay;
    if (request.bind().replay())
      replay = session->UpdatesAfter(request.bind().replay_after_timestamp_ns());
    pb::StreamResponse bound;
    *bound.mutable_bound()->mutable_session() = session->Info();
    bound.mutable_bound()->set_replay_count(static_cast<int32_t>(replay.size()));
    bool ok = stream->Write(bound);
    if (ok) {
      for (const pb::FrameUpdate& update : replay) {
        pb::StreamResponse replayed;
        *replayed.mutable_update() = update;
        if (!(ok = stream->Write(replayed))) break;
      }
    }
    if (!ok) {
      session->Unbind(&handle);
      return grpc::Status(grpc::StatusCode::CANCELLED, "client went away while binding");
    }
  }

  std::atomic<bool> write_failed{false};
  std::thread worker([&] {
    if (!RunWorker(session.get(), &queue, stream, metrics_)) {
      // The client is gone: unblock the reader (in Read or in a full Push).
      write_failed = true;
      queue.Abort();
      context->TryCancel();
    } else if (handle.taken_over) {
      // Tell the client why before ending the call (a cancelled call reaches
      // the client as CANCELLED, which it would take for a network failure).
      pb::StreamResponse notice;
      FillError(-1,
                0,
                absl::AbortedError(absl::StrCat(
                    "stream taken over by a newer stream for session '", session->id(), "'")),
                &notice);
      stream->Write(notice);
      context->TryCancel();
    }
  });

  // Reader: decode and validate on this thread, in parallel with the engine.
  while (stream->Read(&request)) {
    QueueItem item;
    item.enqueued = std::chrono::steady_clock::now();
    if (request.has_frame()) {
      const pb::Frame& frame = request.frame();
      if (metrics_) metrics_->BytesReceived(static_cast<int64_t>(request.ByteSizeLong()));
      item.index = frame.index();
      item.timestamp_ns = frame.timestamp_ns();
      const auto start = std::chrono::steady_clock::now();
      absl::StatusOr<StereoFrame> decoded = FrameFromProto(frame, session->format());
      if (decoded.ok()) {
        if (const StereoRectifier* rectifier = session->rectifier()) rectifier->Rectify(&*decoded);
        item.frame = std::move(*decoded);
      } else {
        item.error = decoded.status();
      }
      item.decode_ms = MsSince(start);
    } else if (request.has_bind()) {
      item.error = absl::FailedPreconditionError(
          absl::StrCat("this stream is already bound to session '", session->id(), "'"));
      item.index = -1;
    } else {
      item.error = absl::InvalidArgumentError("empty StreamRequest (neither bind nor frame)");
      item.index = -1;
    }
    if (!queue.Push(std::move(item))) break;  // taken over, closing or draining
  }
  const bool cancelled = context->IsCancelled() || handle.taken_over || write_failed;
  if (cancelled) {
    const int discarded = queue.Abort();
    if (discarded > 0)
      VLOG(1) << "session " << session->id() << ": " << discarded << " queued frame(s) discarded";
  } else {
    queue.CloseInput();  // half-close or drain: answer every queued frame
  }
  worker.join();
  session->Unbind(&handle);
  VLOG(1) << "session " << session->id() << ": stream ended";
  if (handle.taken_over) {
    return grpc::Status(
        grpc::StatusCode::ABORTED,
        absl::StrCat("stream taken over by a newer stream for session '", session->id(), "'"));
  }
  if (session->closed()) {
    return grpc::Status(grpc::StatusCode::FAILED_PRECONDITION,
                        absl::StrCat("session '", session->id(), "' was closed or unloaded"));
  }
  if (handle.shutdown) {
    return grpc::Status(grpc::StatusCode::UNAVAILABLE,
                        "server is shutting down; resume the session later");
  }
  if (context->IsCancelled()) return grpc::Status(grpc::StatusCode::CANCELLED, "stream cancelled");
  return grpc::Status::OK;
}

grpc::Status SlamServiceImpl::GetMap(grpc::ServerContext* context,
                                     const pb::GetMapRequest* request,
                                     grpc::ServerWriter<pb::MapChunk>* writer) {
  absl::StatusOr<std::string> principal = auth_->Authenticate(*context);
  if (!principal.ok()) return ToGrpcStatus(principal.status());
  absl::StatusOr<std::shared_ptr<Session>> session =
      manager_->Get(request->session_id(), *principal);
  if (!session.ok()) return ToGrpcStatus(session.status());
  if (request->max_chunk_bytes() < 0) {
    return grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, "max_chunk_bytes is negative");
  }
  int64_t frames = 0;
  absl::StatusOr<MapSnapshot> map = (*session)->Snapshot(&frames);
  if (!map.ok()) return ToGrpcStatus(map.status());
  MapChunkOptions options;
  const int64_t requested =
      request->max_chunk_bytes() == 0 ? (1 << 20) : request->max_chunk_bytes();
  options.max_chunk_bytes = std::clamp<int64_t>(requested, 64 << 10, info_.max_message_bytes);
  options.skip_points = request->skip_points();
  options.skip_keyframes = request->skip_keyframes();
  options.skip_clusters = request->skip_clusters();
  options.skip_trajectories = request->skip_trajectories();
  options.skip_objects = request->skip_objects();
  options.frames_processed = frames;
  for (const pb::MapChunk& chunk : MapToChunks(*map, options)) {
    if (context->IsCancelled())
      return grpc::Status(grpc::StatusCode::CANCELLED, "map fetch cancelled");
    if (!writer->Write(chunk)) return grpc::Status(grpc::StatusCode::CANCELLED, "client went away");
  }
  return grpc::Status::OK;
}

grpc::Status SlamServiceImpl::CloseSession(grpc::ServerContext* context,
                                           const pb::CloseSessionRequest* request,
                                           pb::CloseSessionResponse* response) {
  absl::StatusOr<std::string> principal = auth_->Authenticate(*context);
  if (!principal.ok()) return ToGrpcStatus(principal.status());
  bool persisted = false;
  absl::StatusOr<pb::SessionInfo> info =
      manager_->Close(request->session_id(), *principal, request->persist(), &persisted);
  if (!info.ok()) return ToGrpcStatus(info.status());
  *response->mutable_session() = *info;
  response->set_persisted(persisted);
  return grpc::Status::OK;
}

grpc::Status SlamServiceImpl::ListSessions(grpc::ServerContext* context,
                                           const pb::ListSessionsRequest* request,
                                           pb::ListSessionsResponse* response) {
  absl::StatusOr<std::string> principal = auth_->Authenticate(*context);
  if (!principal.ok()) return ToGrpcStatus(principal.status());
  for (pb::SessionInfo& info : manager_->List(*principal))
    *response->add_sessions() = std::move(info);
  return grpc::Status::OK;
}

grpc::Status SlamServiceImpl::PersistSession(grpc::ServerContext* context,
                                             const pb::PersistSessionRequest* request,
                                             pb::PersistSessionResponse* response) {
  absl::StatusOr<std::string> principal = auth_->Authenticate(*context);
  if (!principal.ok()) return ToGrpcStatus(principal.status());
  absl::StatusOr<SessionRecord> record = manager_->Persist(request->session_id(), *principal);
  if (!record.ok()) return ToGrpcStatus(record.status());
  response->set_frames_persisted(record->frames_processed);
  response->set_last_frame_index(record->last_frame_index);
  response->set_last_timestamp_ns(record->last_timestamp_ns);
  return grpc::Status::OK;
}

grpc::Status SlamServiceImpl::ResumeSession(grpc::ServerContext* context,
                                            const pb::ResumeSessionRequest* request,
                                            pb::ResumeSessionResponse* response) {
  absl::StatusOr<std::string> principal = auth_->Authenticate(*context);
  if (!principal.ok()) return ToGrpcStatus(principal.status());
  bool loaded = false;
  absl::StatusOr<std::shared_ptr<Session>> session =
      manager_->Resume(request->session_id(), request->resume_token(), *principal, &loaded);
  if (!session.ok()) return ToGrpcStatus(session.status());
  *response->mutable_session() = (*session)->Info();
  response->set_loaded_from_disk(loaded);
  return grpc::Status::OK;
}

grpc::Status SlamServiceImpl::GetServerInfo(grpc::ServerContext* context,
                                            const pb::GetServerInfoRequest* request,
                                            pb::GetServerInfoResponse* response) {
  absl::StatusOr<std::string> principal = auth_->Authenticate(*context);
  if (!principal.ok()) return ToGrpcStatus(principal.status());
  const SessionManagerOptions& o = manager_->options();
  response->set_version(info_.version);
  response->set_protocol("twistslam.v1");
  pb::ServerLimits* limits = response->mutable_limits();
  limits->set_max_sessions(o.max_sessions);
  limits->set_max_message_bytes(info_.max_message_bytes);
  limits->set_max_queue_capacity(o.limits.max_queue_capacity);
  limits->set_default_queue_capacity(o.limits.default_queue_capacity);
  limits->set_default_idle_timeout_s(o.limits.default_idle_timeout_s);
  limits->set_max_idle_timeout_s(o.limits.max_idle_timeout_s);
  limits->set_max_image_width(o.limits.max_image_width);
  limits->set_max_image_height(o.limits.max_image_height);
  for (const std::string& c : info_.capabilities) response->add_capabilities(c);
  response->set_active_sessions(manager_->num_loaded());
  response->set_auth_required(auth_->enabled());
  response->set_serving(manager_->accepting());
  return grpc::Status::OK;
}

grpc::Status SlamServiceImpl::GetMetrics(grpc::ServerContext* context,
                                         const pb::GetMetricsRequest* request,
                                         pb::GetMetricsResponse* response) {
  absl::StatusOr<std::string> principal = auth_->Authenticate(*context);
  if (!principal.ok()) return ToGrpcStatus(principal.status());
  response->set_prometheus_text(MetricsText());
  return grpc::Status::OK;
}

std::string SlamServiceImpl::MetricsText() const {
  return metrics_->PrometheusText(manager_->Gauges());
}

}  // namespace twist::server
