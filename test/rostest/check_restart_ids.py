#!/usr/bin/python3
"""rostest: a session's id is its store id for life, across back-end restarts.

1. Session 0 is recorded from a bag and finished; start_session opens session 1, recorded from the
   second bag and finished; session 0 is deleted (delete_session). The store now holds session 1
   only: a restart used to number it 0, an id that had belonged to another session.
2. kill -9 of the back-end, respawned by roslaunch: list_sessions shows session 1 'session_1'; the
   export service and export_survey (on the store, read-only) both name its files session_1.* and
   its map's map_1.*; the store's own row is id 1.
3. start_session 'dive_c' takes id 2 (past every stored and deleted id), recorded from a third bag.
4. kill -9 again: sessions 1 'session_1' and 2 'dive_c' keep id and name in list_sessions, in the
   export service's file names, in export_survey's and in the store's rows.
"""
import os
import shutil
import sqlite3
import subprocess
import tempfile
import threading
import time
import unittest

import rospy
import rostest
from pipeline_fixture import (NS, SENSOR_TOPICS, SURVEY, kill_backend_and_await_respawn, make_mission, tool,
                              wait_for_subscribers, wait_until_quiet)
from uw_multislam.msg import Keyframe, SessionState, Status
from uw_multislam.srv import DeleteSession, ExportSurvey, FinishSession, ListSessions, StartSession

# The fixture's two sessions and a third, 1000 s after the second (the odometry skips frames older
# than its last one, so each bag played must be later than the one before).
SURVEY_3 = SURVEY + """  - name: s2
    camera: {image_width: 240, image_height: 180, fx: 220, fy: 220, cx: 119.5, cy: 89.5}
    mission: {pattern: loop, start_m: [6.0, 5.0], length_m: 3.0, width_m: 2.0, laps: 1.0, speed_m_s: 0.35,
              frame_period_s: 1.0, altitude_m: 1.6, start_time_s: 2000}
"""
TRACKS = ("tum", "kitti", "csv", "g2o")


class RestartIdsTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp, cls.mission = make_mission("uwms_restart_ids_", survey=SURVEY_3)
        cls.lock = threading.Lock()
        cls.keyframes = []
        cls.last = time.time()

        def on_keyframe(msg):
            with cls.lock:
                cls.keyframes.append(msg)
                cls.last = time.time()
        cls.subs = [rospy.Subscriber(NS + "/keyframes", Keyframe, on_keyframe, queue_size=1000)]
        cls.store = rospy.get_param(NS + "/backend_node/store_path")
        cls.root = rospy.get_param(NS + "/backend_node/export_root")
        rospy.wait_for_service(NS + "/list_sessions", timeout=60)
        wait_for_subscribers(["/camera/image_raw", NS + "/keyframes"], "/check_restart_ids")

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def call(self, name, srv_type, *args, **kwargs):
        """A service call, retried while a respawned back-end is not yet answering."""
        deadline = time.time() + 60
        while True:
            try:
                rospy.wait_for_service(NS + "/" + name, timeout=max(1.0, deadline - time.time()))
                return rospy.ServiceProxy(NS + "/" + name, srv_type)(*args, **kwargs)
            except (rospy.ServiceException, rospy.ROSException):
                if time.time() > deadline:
                    raise
                time.sleep(0.5)

    def listed(self):
        res = self.call("list_sessions", ListSessions)
        self.assertEqual(res.status.code, Status.OK, res.status.message)
        return {s.session: s for s in res.sessions}

    def names(self):
        return {i: s.name for i, s in self.listed().items()}

    def record(self, bag, session):
        """Plays a bag into the recording session `session` and waits until the back-end holds every
        keyframe the odometry published for it; then finish_session."""
        subprocess.run(["rosbag", "play", "-q", "-r", "4", os.path.join(self.mission, bag), "--topics"] + SENSOR_TOPICS,
                       check=True, timeout=120)
        wait_until_quiet(self.lock, lambda: self.last, 3.0, timeout=60)
        with self.lock:
            sent = len({k.keyframe for k in self.keyframes if k.session == session})
        self.assertGreater(sent, 5, "keyframes of session %d published" % session)
        deadline = time.time() + 30
        while time.time() < deadline:
            s = self.listed().get(session)
            if s is not None and s.num_keyframes == sent:
                break
            time.sleep(0.2)
        self.assertEqual(self.listed()[session].num_keyframes, sent, "the back-end holds session %d" % session)
        res = self.call("finish_session", FinishSession)
        self.assertEqual((res.status.code, res.session), (Status.OK, session), res.status.message)

    def restart(self):
        kill_backend_and_await_respawn(self, "/check_restart_ids")

    def exported(self, session, folder):
        """The export service's file names for a session and for its map (tracks only)."""
        names = set()
        for as_map in (False, True):
            res = self.call("export", ExportSurvey, session=session, map=as_map, folder=folder, origin="",
                            resolution_m=0.0, no_mosaic=True)
            self.assertEqual(res.status.code, Status.OK, "%s: %s" % (session, res.status.message))
            names |= {os.path.basename(f) for f in res.files}
        return names

    def export_survey(self):
        """export_survey's track file names for the whole store (read-only beside the back-end)."""
        out = tempfile.mkdtemp(prefix="export_survey_", dir=self.tmp)
        r = subprocess.run([tool("export_survey"), "--db", self.store, "--out", out, "--no-mosaic"],
                           capture_output=True, text=True, timeout=120)
        self.assertEqual(r.returncode, 0, r.stderr)
        return {n for n in os.listdir(out) if n.rsplit(".", 1)[-1] in TRACKS}

    def store_rows(self):
        with sqlite3.connect("file:%s?mode=ro" % self.store, uri=True) as c:
            return dict(c.execute("SELECT id, name FROM sessions ORDER BY id"))

    def expect_everywhere(self, expected, folder):
        """Each session of `expected` ({id: name}) under its id and name in list_sessions, the store,
        the export service's files and export_survey's (each alone in its map: map_<id>)."""
        self.assertEqual(self.names(), expected, "list_sessions")
        self.assertTrue(all(s.state == SessionState.UNLOADED for s in self.listed().values()))
        self.assertEqual(self.store_rows(), expected, "the store's rows")
        files = {"%s_%d.%s" % (kind, i, ext) for i in expected for kind in ("session", "map") for ext in TRACKS}
        service = set()
        for i, name in expected.items():
            by_name = self.exported(name, "%s/by_name_%d" % (folder, i))
            by_id = self.exported(str(i), "%s/by_id_%d" % (folder, i))
            self.assertEqual(by_name, by_id, "session %d by name and by id" % i)
            service |= by_id
        self.assertEqual(service, files, "the export service's files")
        self.assertEqual(self.export_survey(), files, "export_survey's files")

    def test_session_ids_survive_two_restarts(self):
        # 1. Sessions 0 and 1, then 0 deleted.
        self.record("s0.bag", 0)
        res = self.call("start_session", StartSession, "")
        self.assertEqual((res.status.code, res.session), (Status.OK, 1), res.status.message)
        self.record("s1.bag", 1)
        res = self.call("delete_session", DeleteSession, "0", True)
        self.assertEqual((res.status.code, res.session), (Status.OK, 0), res.status.message)
        before = self.listed()
        self.assertEqual({i: s.name for i, s in before.items()}, {1: "session_1"})

        # 2. First restart: session 1 is still 1, everywhere.
        self.restart()
        self.expect_everywhere({1: "session_1"}, "first")
        self.assertEqual(self.listed()[1].num_keyframes, before[1].num_keyframes)
        res = self.call("delete_session", DeleteSession, "0", True)  # the deleted id names nothing now
        self.assertEqual(res.status.code, Status.NOT_FOUND, res.status.message)

        # 3. A new session takes the next id, past the deleted one: 2.
        res = self.call("start_session", StartSession, "dive_c")
        self.assertEqual((res.status.code, res.session), (Status.OK, 2), res.status.message)
        self.record("s2.bag", 2)
        with self.lock:
            self.assertEqual(sorted({k.session for k in self.keyframes}), [0, 1, 2], "the odometry's sessions")

        # 4. Second restart: both keep id and name.
        self.restart()
        self.expect_everywhere({1: "session_1", 2: "dive_c"}, "second")
        print("restart ids: %s after two restarts, in list_sessions, the store, export and export_survey" %
              self.names())


if __name__ == "__main__":
    rospy.init_node("check_restart_ids")
    rostest.rosrun("uw_multislam", "check_restart_ids", RestartIdsTest)
