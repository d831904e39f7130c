"""A torchrun rank whose peer stopped mid-collective (its loader worker killed, a shard it could not
read): gloo's RuntimeError is one line (runtime.peer_stopped), not a traceback after the peer's own
one-line error."""
from sc3d_train.data.loader import worker_death
from sc3d_train.loop.runtime import PeerStopped, peer_stopped

#: what the healthy rank of a 2-rank CPU fit raised when the other rank's loader worker was killed
#: (kill -9; measured 2026-12-08, torch's gloo)
GLOO_CLOSED = ("[/__w/pytorch/pytorch/third_party/gloo/gloo/transport/tcp/pair.cc:553] Connection closed by "
               "peer [127.0.0.1]:31140. This is typically caused by a remote worker crashing. Check the logs of "
               "the remote worker before reporting an error. GLHF! \U0001f3d6\ufe0f")
GLOO_RESET = ("[/__w/pytorch/pytorch/third_party/gloo/gloo/transport/tcp/pair.cc:537] Read error "
              "[127.0.0.1]:24713: Connection reset by peer. This is typically caused by a remote worker hanging "
              "or bugs in the application.")


def test_a_peer_that_stopped_is_one_line_naming_the_other_ranks_error():
    for text in (GLOO_CLOSED, GLOO_RESET):
        e = peer_stopped(RuntimeError(text), "last good checkpoint: RUN/checkpoints/last.pt (resume with --resume)")
        assert isinstance(e, PeerStopped) and isinstance(e, OSError)
        assert "\n" not in str(e) and "another rank stopped" in str(e) and "last good checkpoint" in str(e)
        assert "GLHF" not in str(e)


def test_other_errors_are_left_alone():
    assert peer_stopped(RuntimeError("mat1 and mat2 shapes cannot be multiplied")) is None
    assert peer_stopped(ValueError("Connection reset by peer")) is None
    assert worker_death(RuntimeError(GLOO_CLOSED)) is None
