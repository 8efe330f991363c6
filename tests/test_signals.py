import os
import signal
import threading

import pytest

from fusion_pf.signals import sigint_deferred


def test_ctrl_c_waits_for_the_end_of_the_block():
    done = []
    with pytest.raises(KeyboardInterrupt):
        with sigint_deferred():
            os.kill(os.getpid(), signal.SIGINT)
            done.append("first")
            with sigint_deferred():
                done.append("nested")
            done.append("last")
    assert done == ["first", "nested", "last"]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_ctrl_c_from_another_thread_is_deferred_too():
    done = []
    with pytest.raises(KeyboardInterrupt):
        with sigint_deferred():
            t = threading.Thread(target=signal.raise_signal, args=(signal.SIGINT,))
            t.start()
            t.join()
            done.append("finished")
    assert done == ["finished"]


def test_no_signal_no_interrupt():
    with sigint_deferred():
        pass
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
