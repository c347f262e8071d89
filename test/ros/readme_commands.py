#!/usr/bin/env python3
"""The README's ROS commands, run as written against a live master (rostest), so that the docs
cannot rot: every line of each README code block marked `<!-- readme-commands ... -->` runs from the
repository root in a bash, in order, after sourcing the devel space's setup.bash as the README's
`source build/devel/setup.bash` does (`roscore &` excepted: rostest provides the master); a line ending in `&` runs in the background (the node), every other
line must exit 0 within a time limit, and what it prints is checked where the README says what it
shows. The block must contain the commands a new user needs: starting the node with rosrun,
playing the bag, the empty merge request, echoing the edge and /diagnostics, rosmsg show of our and
LSD-SLAM's messages, and the Python import.
"""
import os
import re
import signal
import subprocess
import sys
import unittest

import rospkg
import rostest

ROOT = rospkg.RosPack().get_path('pcr_pro')
README = os.path.join(ROOT, 'README.md')
# A merge takes a few seconds; a bag plays in one; allow for a busy machine.
TIMEOUT_S = 120


def readme_commands():
    """The command lines of the marked blocks, without their trailing `  # comments`."""
    with open(README) as f:
        text = f.read()
    blocks = re.findall(r'<!-- readme-commands[^>]*-->\s*```sh\n(.*?)```', text, re.S)
    commands = []
    for block in blocks:
        for line in block.splitlines():
            command = re.split(r'\s{2,}#', line)[0].strip()
            if command and not command.startswith('source ') and not command.startswith('roscore'):
                commands.append(command)
    return commands


def environment():
    """The test's ROS environment, with Debian's Python first on PATH as on a fresh Debian 12."""
    env = dict(os.environ)
    env['PATH'] = '/usr/bin:/bin:' + env.get('PATH', '')
    return env


def devel_space():
    """The devel space of the build under test (the first entry of CMAKE_PREFIX_PATH)."""
    devel = os.environ.get('CMAKE_PREFIX_PATH', '').split(':')[0]
    if not os.path.isfile(os.path.join(devel, 'setup.bash')):
        raise RuntimeError('no devel space with a setup.bash in CMAKE_PREFIX_PATH: %r' % devel)
    return devel


def as_user(command):
    """The command as a user runs it: in a bash that has sourced the devel space's setup.bash, as the
    README's `source build/devel/setup.bash` line does (the environment rostest gets from catkin is
    cached when the build is configured, before the devel space holds the Python messages, so it
    lacks their PYTHONPATH on a fresh build), talking to the test's master."""
    return 'source %s/setup.bash && export ROS_MASTER_URI=%s && %s' % (
        devel_space(), os.environ['ROS_MASTER_URI'], command)


class ReadmeCommands(unittest.TestCase):
    def test_the_readme_commands_work_as_written(self):
        commands = readme_commands()
        self.assertTrue(commands, 'no <!-- readme-commands --> block in ' + README)
        required = {
            'the node with rosrun': r'^rosrun pcr_pro merge_node\b.*&$',
            'the bag': r'^rosbag play .*\$PCR_PRO_SIM_DIR/demo/pcr_pro_two_agents\.bag',
            'the empty merge request': r'^rosservice call /merge_node/merge "\{\}"$',
            'the edge': r'^rostopic echo .*/merge_node/edge$',
            'the diagnostics': r'^rostopic echo .*/diagnostics$',
            'our message': r'^rosmsg show pcr_pro/MapEdge$',
            "LSD-SLAM's message": r'^rosmsg show lsd_slam_viewer/keyframeMsg$',
            'the Python import': r'^python3 -c .*from pcr_pro\.msg import .*from lsd_slam_viewer\.msg import',
        }
        for what, pattern in required.items():
            self.assertTrue(any(re.search(pattern, c) for c in commands),
                            'the README block lacks %s (%s): %s' % (what, pattern, commands))
        # What some commands must print (the README says it is there).
        expected = {
            r'^rosservice call /merge_node/merge': ['status_name: "OK"', 'scale:', 'covariance:'],
            r'^rostopic echo .*/merge_node/edge$': ['source_agent: "agent_b"', 'scale:', 'information:'],
            r'^rostopic echo .*/merge_node/edge_history$': ['records:', 'trigger: "service"'],
            r'^rosservice call /merge_node/edges': ['records:', 'edge:'],
            r'^rostopic echo .*/diagnostics$': ['keyframes', 'merges_ok'],
            r'^rosmsg show pcr_pro/MapEdge$': ['geometry_msgs/PoseWithCovariance pose', 'float64[36] information'],
            r'^rosmsg show lsd_slam_viewer/keyframeMsg$': ['float32[7] camToWorld', 'uint8[] pointcloud'],
            # LSD-SLAM's own MD5 of lsd_slam_viewer/keyframeMsg: our Python class talks to LSD-SLAM.
            r'^python3 -c': ['42d4108dbb7d0e5d166eb68dd4054826'],
        }
        background = []
        try:
            for command in commands:
                if command.endswith('&'):
                    background.append(subprocess.Popen(as_user(command[:-1]), shell=True, cwd=ROOT, env=environment(),
                                                       executable='/bin/bash',
                                                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                                       start_new_session=True))
                    continue
                run = subprocess.run(as_user(command), shell=True, cwd=ROOT, env=environment(), capture_output=True,
                                     executable='/bin/bash',
                                     text=True, timeout=TIMEOUT_S)
                self.assertEqual(run.returncode, 0, '`%s` failed (exit %d):\n%s\n%s'
                                 % (command, run.returncode, run.stdout[-2000:], run.stderr[-2000:]))
                for pattern, words in expected.items():
                    if re.search(pattern, command):
                        for word in words:
                            self.assertIn(word, run.stdout, '`%s` printed no %r:\n%s' % (command, word, run.stdout[-3000:]))
                for p in background:
                    self.assertIsNone(p.poll(), 'a background command of the README died (exit %s)' % p.returncode)
        finally:
            for p in background:
                os.killpg(p.pid, signal.SIGINT)
            for p in background:
                try:
                    p.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    os.killpg(p.pid, signal.SIGKILL)


if __name__ == '__main__':
    rostest.rosrun('pcr_pro', 'readme_commands', ReadmeCommands, sys.argv)
