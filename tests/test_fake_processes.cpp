// The in-process fake of N ranks (tests/fake_processes.hpp): every collective of Communicator with
// MPI's semantics (engine/run/processes.cpp) for N = 1, 2, 3, 5, many in a row, and misuse that
// must fail the test rather than hang it.
#include "fake_processes.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <string>
#include <thread>
#include <vector>

namespace stiffmd {
namespace {

using fake::run_ranks;

class FakeRanks : public ::testing::TestWithParam<int> {};

TEST_P(FakeRanks, EachRankHasItsOwnRankAndTheSize) {
  const int n = GetParam();
  std::vector<int> seen(n, -1), sizes(n, -1);
  run_ranks(n, [&](const Communicator& comm) {
    seen[comm.rank()] = comm.rank();
    sizes[comm.rank()] = comm.size();
    EXPECT_EQ(comm.root(), comm.rank() == 0);
    EXPECT_EQ(comm.native(), nullptr);
  });
  for (int r = 0; r < n; ++r) {
    EXPECT_EQ(seen[r], r);
    EXPECT_EQ(sizes[r], n);
  }
}

TEST_P(FakeRanks, ReductionsAreElementWiseOverTheRanks) {
  const int n = GetParam();
  run_ranks(n, [&](const Communicator& comm) {
    const int r = comm.rank();
    double d[3] = {r + 1.0, 0.5 * r, -static_cast<double>(r)};
    comm.sum(d, 3);
    EXPECT_EQ(d[0], n * (n + 1) / 2.0);
    EXPECT_EQ(d[1], 0.25 * n * (n - 1));
    EXPECT_EQ(d[2], -0.5 * n * (n - 1));
    // Past 2⁵³: an int64 sum that went through doubles would lose the last bits.
    std::int64_t big[2] = {(std::int64_t{1} << 60) + r, -r};
    comm.sum(big, 2);
    EXPECT_EQ(big[0], n * (std::int64_t{1} << 60) + n * (n - 1) / 2);
    EXPECT_EQ(big[1], -n * (n - 1) / 2);
    double m[3] = {static_cast<double>(r), -10.0 - r, r == n - 1 ? std::numeric_limits<double>::infinity() : 0.0};
    comm.max(m, 3);
    EXPECT_EQ(m[0], n - 1.0);
    EXPECT_EQ(m[1], -10.0);
    EXPECT_EQ(m[2], std::numeric_limits<double>::infinity());
    std::int64_t lo[2] = {100 - r, r == n / 2 ? std::int64_t{-7} : std::int64_t{5}};
    comm.min(lo, 2);
    EXPECT_EQ(lo[0], 100 - (n - 1));
    EXPECT_EQ(lo[1], -7);
    EXPECT_EQ(comm.sum(1.5), 1.5 * n);
    EXPECT_EQ(comm.max(-static_cast<double>(r)), 0.0);
    comm.sum(static_cast<double*>(nullptr), 0);  // no values: still a rendezvous
  });
}

TEST_P(FakeRanks, BroadcastsGiveTheRootsValuesToEveryRank) {
  const int n = GetParam();
  run_ranks(n, [&](const Communicator& comm) {
    const int r = comm.rank();
    std::int64_t i[2] = {r == 0 ? 42 : -1, r == 0 ? std::int64_t{1} << 62 : 0};
    comm.broadcast(i, 2);
    EXPECT_EQ(i[0], 42);
    EXPECT_EQ(i[1], std::int64_t{1} << 62);
    double d[2] = {r == 0 ? 0.1 : std::nan(""), r == 0 ? -3.0 : 7.0};
    comm.broadcast(d, 2);
    EXPECT_EQ(d[0], 0.1);
    EXPECT_EQ(d[1], -3.0);
    for (int root = 0; root < n; ++root) {
      std::string text = r == root ? "from rank " + std::to_string(root) + std::string(1000, 'x') : "junk";
      comm.broadcast(text, root);
      EXPECT_EQ(text, "from rank " + std::to_string(root) + std::string(1000, 'x'));
      std::string empty = r == root ? "" : "not empty";
      comm.broadcast(empty, root);
      EXPECT_EQ(empty, "");
    }
  });
}

// What rank s sends rank r: (s r k) for k < count(s, r), some empty, some messages to itself.
int count(int s, int r) {
  return (3 * s + r) % 4;
}
double word(int s, int r, int k) {
  return 100.0 * s + 10.0 * r + k;
}
std::vector<std::vector<double>> messages_of(int s, int n) {
  std::vector<std::vector<double>> send(n);
  for (int r = 0; r < n; ++r)
    for (int k = 0; k < count(s, r); ++k) send[r].push_back(word(s, r, k));
  return send;
}

TEST_P(FakeRanks, ExchangeDeliversEachRanksMessageToItsReceiver) {
  const int n = GetParam();
  run_ranks(n, [&](const Communicator& comm) {
    const int me = comm.rank();
    const std::vector<std::vector<double>> send = messages_of(me, n);
    std::vector<std::vector<double>> recv(n + 2, std::vector<double>(9, -1.0));  // resized by exchange
    comm.exchange(send, recv);
    ASSERT_EQ(static_cast<int>(recv.size()), n);
    for (int s = 0; s < n; ++s) {
      ASSERT_EQ(static_cast<int>(recv[s].size()), count(s, me)) << "from " << s;
      for (int k = 0; k < count(s, me); ++k) EXPECT_EQ(recv[s][k], word(s, me, k));
    }
    // The counts known: recv keeps its buffers (the same storage), filled.
    std::vector<std::vector<double>> known(n);
    for (int s = 0; s < n; ++s) known[s].assign(count(s, me), -1.0);
    std::vector<const double*> storage;
    for (const auto& b : known) storage.push_back(b.data());
    comm.exchange_known(send, known);
    for (int s = 0; s < n; ++s) {
      EXPECT_EQ(known[s].data(), storage[s]);
      for (int k = 0; k < count(s, me); ++k) EXPECT_EQ(known[s][k], word(s, me, k));
    }
  });
}

TEST_P(FakeRanks, GatherGivesRankZeroEveryRanksValuesInRankOrder) {
  const int n = GetParam();
  run_ranks(n, [&](const Communicator& comm) {
    const int me = comm.rank();
    std::vector<double> mine;
    if (me != 1)
      for (int k = 0; k <= me; ++k) mine.push_back(10.0 * me + k);
    std::vector<std::vector<double>> all(3, std::vector<double>(2, -1.0));  // replaced on rank 0, cleared elsewhere
    comm.gather(mine, all);
    if (me != 0) {
      EXPECT_TRUE(all.empty());
      return;
    }
    ASSERT_EQ(static_cast<int>(all.size()), n);
    for (int r = 0; r < n; ++r) {
      ASSERT_EQ(all[r].size(), r == 1 ? 0u : static_cast<size_t>(r + 1)) << r;
      for (size_t k = 0; k < all[r].size(); ++k) EXPECT_EQ(all[r][k], 10.0 * r + k);
    }
  });
}

TEST_P(FakeRanks, FirstProblemIsTheLowestFailingRanksOnEveryRank) {
  const int n = GetParam();
  run_ranks(n, [&](const Communicator& comm) {
    const int me = comm.rank();
    const Communicator::Problem none = comm.first_problem("");
    EXPECT_EQ(none.rank, -1);
    EXPECT_EQ(none.text, "");
    // Ranks n − 1 and (n − 1) / 2 have one: the lower one's is everyone's.
    const bool failing = me == n - 1 || me == (n - 1) / 2;
    const Communicator::Problem p = comm.first_problem(failing ? "bad on " + std::to_string(me) : "");
    const int first = (n - 1) / 2;
    EXPECT_EQ(p.rank, first);
    EXPECT_EQ(p.text, "bad on " + std::to_string(first));
    EXPECT_EQ(p.said(), first > 0 ? "rank " + std::to_string(first) + ": bad on " + std::to_string(first) : "bad on 0");
    // agree(): an InputError on the last rank becomes AgreedInputError on every rank.
    if (n > 1) {
      try {
        agree(&comm, [&] {
          if (me == n - 1) throw InputError("deck");
        });
        ADD_FAILURE() << "no error on rank " << me;
      } catch (const AgreedInputError& e) {
        EXPECT_EQ(std::string(e.what()), "rank " + std::to_string(n - 1) + ": deck");
      }
    }
  });
}

// Thousands of rendezvous in a row, each rank's values changing between them: a barrier that let
// a rank run ahead into the next call would mix two calls' values.
TEST_P(FakeRanks, ManyCollectivesInARowKeepTheirValuesApart) {
  const int n = GetParam();
  run_ranks(n, [&](const Communicator& comm) {
    for (int step = 0; step < 2000; ++step) {
      double v = step + comm.rank();
      comm.sum(&v, 1);
      ASSERT_EQ(v, n * step + n * (n - 1) / 2.0) << "step " << step;
      std::vector<std::vector<double>> send(n, std::vector<double>{static_cast<double>(step)}), recv;
      comm.exchange(send, recv);
      for (int s = 0; s < n; ++s) ASSERT_EQ(recv[s], std::vector<double>{static_cast<double>(step)});
    }
  });
}

TEST_P(FakeRanks, EachRankCountsItsCollectives) {
  run_ranks(GetParam(), [&](const fake::FakeCommunicator& comm) {
    EXPECT_EQ(comm.collectives(), 0);
    comm.sum(1.0);
    std::vector<std::vector<double>> all;
    comm.gather({}, all);
    comm.first_problem("");  // min, and no broadcast when no rank has a problem
    EXPECT_EQ(comm.collectives(), 3);
  });
}

INSTANTIATE_TEST_SUITE_P(Ranks, FakeRanks, ::testing::Values(1, 2, 3, 5),
                         [](const ::testing::TestParamInfo<int>& info) { return std::to_string(info.param); });

// ---- misuse fails instead of hanging --------------------------------------------------------

std::string message_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const std::exception& e) {
    return e.what();
  }
  return "(no exception)";
}

TEST(FakeRanksMisuse, ARanksExceptionReachesTheCallerAndFreesTheOthers) {
  std::atomic<int> aborted = 0;
  const std::string what = message_of([&] {
    run_ranks(3, [&](const Communicator& comm) {
      if (comm.rank() == 1) throw std::runtime_error("rank 1 fails");
      try {
        comm.sum(1.0);  // waits for rank 1, which never comes
      } catch (const fake::RankAborted&) {
        ++aborted;
        throw;
      }
    });
  });
  EXPECT_EQ(what, "rank 1 fails");
  EXPECT_EQ(aborted, 2);
}

TEST(FakeRanksMisuse, ARankThatReturnsEarlyFailsTheOthersWaits) {
  const std::string what = message_of([] {
    run_ranks(3, [](const Communicator& comm) {
      if (comm.rank() != 2) comm.sum(1.0);
    });
  });
  EXPECT_NE(what.find("waits in sum(double), but rank 2 returned"), std::string::npos) << what;
}

TEST(FakeRanksMisuse, DifferentCollectivesOrCountsAreRefusedOnEveryRank) {
  EXPECT_NE(message_of([] {
              run_ranks(2, [](const Communicator& comm) {
                double v = 1.0;
                if (comm.rank() == 0)
                  comm.sum(&v, 1);
                else
                  comm.max(&v, 1);
              });
            }).find("while rank"),
            std::string::npos);
  EXPECT_NE(message_of([] {
              run_ranks(3, [](const Communicator& comm) {
                double v[2] = {1.0, 2.0};
                comm.sum(v, comm.rank() == 2 ? 1 : 2);
              });
            }).find("passes"),
            std::string::npos);
  EXPECT_NE(message_of([] {
              run_ranks(2, [](const Communicator& comm) {
                std::string s = "x";
                comm.broadcast(s, comm.rank());
              });
            }).find("names root"),
            std::string::npos);
  // exchange_known with a receiver expecting another count than its sender sends.
  EXPECT_NE(message_of([] {
              run_ranks(2, [](const Communicator& comm) {
                std::vector<std::vector<double>> send(2, std::vector<double>(3, 1.0)), recv(2, std::vector<double>(3));
                if (comm.rank() == 1) recv[0].resize(2);
                comm.exchange_known(send, recv);
              });
            }).find("rank 0 sends 3 values to rank 1, which expects 2"),
            std::string::npos);
}

TEST(FakeRanksMisuse, AWaitPastTheTimeoutFails) {
  const auto start = std::chrono::steady_clock::now();
  const std::string what = message_of([] {
    run_ranks(
        2,
        [](const Communicator& comm) {
          if (comm.rank() == 1) std::this_thread::sleep_for(std::chrono::milliseconds(400));
          comm.sum(1.0);
        },
        std::chrono::milliseconds(50));
  });
  EXPECT_NE(what.find("waited more than 50 ms in sum(double)"), std::string::npos) << what;
  EXPECT_LT(std::chrono::steady_clock::now() - start, std::chrono::seconds(5));
}

}  // namespace
}  // namespace stiffmd
