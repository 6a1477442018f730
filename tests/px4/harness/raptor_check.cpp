// Loads a policy.tar with RLtools' own tar loader into the policy type PX4's mc_raptor compiles in
// (src/modules/mc_raptor/blob/policy.h: dense 22->16 ReLU, GRU 16, dense 16->4 identity, declared
// for sequences of 500 x 2), runs mc_raptor's start-up check (Raptor::init and Raptor::test_policy:
// the stored example, 2 sequences x 5 steps, mean absolute difference < 1e-5, NaN refused) and,
// with `fly`, steps the loaded policy through RLtools' L2F inference executor at mc_raptor's timing
// (mc_raptor.hpp EXECUTOR_CONFIG: 100 Hz native, control on every 400 Hz gyro update, action
// history of 1, previous action fed back as mc_raptor's observe() does).
//
// Written for quadpilot's tests (tests/px4/test_rltools_loader.py); the RLtools headers are not
// ours: they come from the `rltools` sdist on PyPI (2.2.1, buffer tar reader) or, with
// -DQP_RLTOOLS_POSIX, from an RLtools checkout that has persist/backends/tar/operations_posix.h
// (the reader mc_raptor uses, over a FILE*).
//
// usage: raptor_check check POLICY_TAR
//        raptor_check fly POLICY_TAR OBSERVATIONS_F32 ACTIONS_OUT_F32
//        raptor_check save POLICY_TAR OUT_TAR   (RLtools' tar writer writes back what it loaded,
//                                                 the example loaded with RLtools' tensor loader)
// OBSERVATIONS_F32: N records of 13 float32 (position 3, quaternion w x y z, linear velocity 3,
// angular velocity 3), one per gyro update 2.5 ms apart. ACTIONS_OUT_F32: N x 4 float32.
// exit 0: accepted (and flown); 1: refused as mc_raptor refuses; 2: usage or I/O. RLtools' own
// asserts abort the process (SIGABRT), as they do in PX4's POSIX build (DefaultCPU).

#include <rl_tools/operations/cpu.h>

#include <rl_tools/nn/layers/dense/operations_generic.h>
#include <rl_tools/nn/layers/gru/operations_generic.h>
#include <rl_tools/nn_models/sequential/operations_generic.h>

#include <rl_tools/inference/executor/executor.h>
#include <rl_tools/inference/applications/l2f/l2f.h>
#include <rl_tools/inference/applications/l2f/operations_generic.h>

// the writer (save mode) first, the readers (and the generic part, once) after it
#define RL_TOOLS_PERSIST_BACKENDS_TAR_OPERATIONS_CPU_NOT_INCLUDE_GENERIC
#include <rl_tools/persist/backends/tar/operations_cpu.h>
#ifdef QP_RLTOOLS_POSIX
#include <rl_tools/persist/backends/tar/operations_posix.h>
#endif
#include <rl_tools/persist/backends/tar/operations_generic.h>
#include <rl_tools/nn/optimizers/adam/instance/persist.h>  // as mc_raptor.hpp; brings the parameters' persist
#include <rl_tools/nn/layers/dense/persist.h>
#include <rl_tools/nn/layers/gru/persist.h>
#include <rl_tools/nn_models/sequential/persist.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <vector>

namespace rlt = rl_tools;
using DEVICE = rlt::devices::DefaultCPU;  // what mc_raptor uses under __PX4_POSIX
using TI = typename DEVICE::index_t;
using T = float;
using RNG = DEVICE::SPEC::RANDOM::ENGINE<>;
using TYPE_POLICY = rlt::numeric_types::Policy<float>;

// the policy type of blob/policy.h, layer by layer
template <typename CONTENT, typename NEXT = rlt::nn_models::sequential::OutputModule>
using Module = typename rlt::nn_models::sequential::Module<CONTENT, NEXT>;
using LAYER_0 = rlt::nn::layers::dense::BindConfiguration<rlt::nn::layers::dense::Configuration<
    TYPE_POLICY, TI, 16, rlt::nn::activation_functions::ActivationFunction::RELU,
    rlt::nn::layers::dense::DefaultInitializer<TYPE_POLICY, TI>, rlt::nn::parameters::groups::Input>>;
using LAYER_1 = rlt::nn::layers::gru::BindConfiguration<
    rlt::nn::layers::gru::Configuration<TYPE_POLICY, TI, 16, rlt::nn::parameters::groups::Normal, false>>;
using LAYER_2 = rlt::nn::layers::dense::BindConfiguration<rlt::nn::layers::dense::Configuration<
    TYPE_POLICY, TI, 4, rlt::nn::activation_functions::ActivationFunction::IDENTITY,
    rlt::nn::layers::dense::DefaultInitializer<TYPE_POLICY, TI>, rlt::nn::parameters::groups::Output>>;
using ACTOR = rlt::nn_models::sequential::Build<rlt::nn::capability::Forward<true, true>,
                                                Module<LAYER_0, Module<LAYER_1, Module<LAYER_2>>>,
                                                rlt::tensor::Shape<TI, 500, 2, 22>>;
constexpr TI EXAMPLE_INPUT_DIM = 22, EXAMPLE_OUTPUT_DIM = 4, EXAMPLE_BATCH = 2;  // policy.h's example

// mc_raptor.hpp, EXECUTOR_CONFIG
using POLICY_TEST = ACTOR::template CHANGE_BATCH_SIZE<TI, 1>::template CHANGE_SEQUENCE_LENGTH<TI, 1>;
using POLICY = ACTOR::template CHANGE_BATCH_SIZE<TI, 1>::template CHANGE_CAPABILITY<rlt::nn::capability::Forward<false, false>>;
constexpr TI TEST_SEQUENCE_LENGTH_ACTUAL = 5, TEST_BATCH_SIZE_ACTUAL = 2, OUTPUT_DIM = 4;
constexpr TI POLICY_CONTROL_FREQUENCY_TRAINING = 100, IMU_GYRO_RATEMAX = 400;
constexpr uint64_t GYRO_INTERVAL_US = 1000000 / IMU_GYRO_RATEMAX;
#ifdef QP_RLTOOLS_POSIX
struct WARNING_LEVELS : rlt::inference::executor::WarningLevelsDefault<TYPE_POLICY> {};
using EXECUTOR_SPEC = rlt::inference::applications::l2f::Specification<
    TYPE_POLICY, TI, uint64_t, 1, OUTPUT_DIM, POLICY, (uint64_t)(2.5 * 1000 * 1000), 10 * 1000 * 1000, true, 8, true,
    WARNING_LEVELS, false>;
#else
// 2.2.1 has no runtime multiple: the compile-time one is what mc_raptor sets at run time for 400 Hz
using EXECUTOR_SPEC = rlt::inference::applications::l2f::Specification<
    TYPE_POLICY, TI, uint64_t, 1, OUTPUT_DIM, POLICY, (uint64_t)(2.5 * 1000 * 1000), 10 * 1000 * 1000, true,
    IMU_GYRO_RATEMAX / POLICY_CONTROL_FREQUENCY_TRAINING, rlt::inference::executor::WarningLevelsDefault<TYPE_POLICY>,
    false>;
#endif

struct Loaded {
    std::vector<char> bytes;  // the file (the buffer reader of 2.2.1 reads from memory)
    FILE* f = nullptr;
    TI input_offset = 0, output_offset = 0;
    char checkpoint_name[100] = "n/a";
    // The file's bytes for RLtools' buffer reader: never a null pointer. An empty vector's data() may
    // be null, and 2.2.1's reader walks from `data` while `ptr <= data + length - 512`: for a real
    // buffer shorter than a block that bound lies below it (nothing read, the entry not found:
    // RLtools' refusal), for a null one it wraps to the top of memory and the reader reads address 0
    // (a segfault of the harness, which mc_raptor's FILE* reader never sees).
    char* data() { static char none[1] = {0}; return bytes.empty() ? none : bytes.data(); }
    const char* data() const { static const char none[1] = {0}; return bytes.empty() ? none : bytes.data(); }
};

// Raptor::init: load the actor, read the checkpoint name, find the example
static bool load_policy(DEVICE& device, const char* path, POLICY& policy, Loaded& loaded) {
    loaded.f = fopen(path, "rb");
    if (!loaded.f) { printf("cannot open %s\n", path); return false; }
    fseek(loaded.f, 0, SEEK_END);
    long size = ftell(loaded.f);
    rewind(loaded.f);
    loaded.bytes.resize(size > 0 ? size : 0);
    if (size > 0 && fread(loaded.data(), 1, size, loaded.f) != (size_t)size) { printf("cannot read %s\n", path); return false; }
    constexpr TI METADATA_BUFFER_SIZE = 256;
    char metadata_buffer[METADATA_BUFFER_SIZE] = {0};
    TI read_size = 0;
    bool successfully_loaded = false;
#ifdef QP_RLTOOLS_POSIX
    using SPEC = rlt::persist::backends::tar::ReaderGroupSpecification<TI, rlt::persist::backends::tar::PosixFileData<TI>>;
    rlt::persist::backends::tar::ReaderGroup<SPEC> reader_group;
    reader_group.data.f = loaded.f;
    reader_group.data.size = size;
    auto actor_group = rlt::get_group(device, reader_group, "actor");
    successfully_loaded = rlt::load(device, policy, actor_group);
    rlt::persist::backends::tar::get(device, reader_group.data, "actor/meta", metadata_buffer, METADATA_BUFFER_SIZE, read_size);
#else
    using SPEC = rlt::persist::backends::tar::ReaderGroupSpecification<TI>;
    rlt::persist::backends::tar::ReaderGroup<SPEC> reader_group;
    reader_group.data = loaded.data();
    reader_group.size = loaded.bytes.size();
    auto actor_group = rlt::get_group(device, reader_group, "actor");
    rlt::load(device, policy, actor_group);  // 2.2.1: void, a failure aborts
    successfully_loaded = true;
    rlt::persist::backends::tar::get(device, loaded.data(), (TI)loaded.bytes.size(), "actor/meta", metadata_buffer, METADATA_BUFFER_SIZE, read_size);
#endif
    TI position = 0, len = 0;
    if (!rlt::persist::backends::tar::seek_in_metadata(device, metadata_buffer, METADATA_BUFFER_SIZE, "checkpoint_name", position, len)) {
        printf("Failed to get checkpoint name from metadata\n");
        return false;
    }
    strncpy(loaded.checkpoint_name, metadata_buffer + position, sizeof(loaded.checkpoint_name));
    loaded.checkpoint_name[len < sizeof(loaded.checkpoint_name) ? len : sizeof(loaded.checkpoint_name) - 1] = '\0';
    if (!successfully_loaded) { printf("Failed to load policy from file %s\n", path); return false; }
    TI input_size = 0, output_size = 0;
#ifdef QP_RLTOOLS_POSIX
    rlt::persist::backends::tar::seek(device, reader_group.data, "example/input/data", loaded.input_offset, input_size);
    rlt::persist::backends::tar::seek(device, reader_group.data, "example/output/data", loaded.output_offset, output_size);
#else
    char* input_ptr = nullptr;
    char* output_ptr = nullptr;
    rlt::persist::backends::tar::get(device, loaded.data(), (TI)loaded.bytes.size(), "example/input/data", input_ptr, input_size);
    rlt::persist::backends::tar::get(device, loaded.data(), (TI)loaded.bytes.size(), "example/output/data", output_ptr, output_size);
    loaded.input_offset = input_ptr ? (TI)(input_ptr - loaded.data()) : 0;
    loaded.output_offset = output_ptr ? (TI)(output_ptr - loaded.data()) : 0;
#endif
    printf("Checkpoint name: %s\n", loaded.checkpoint_name);
    return true;
}

// Raptor::test_policy, file variant: the same batch, length, reads, NaN asserts and bar
static bool test_policy(DEVICE& device, RNG& rng, POLICY& policy, Loaded& loaded) {
    POLICY_TEST::template Buffer<false> buffers_test;
    POLICY_TEST::template State<false> policy_state_test;
    rlt::Tensor<rlt::tensor::Specification<T, TI, rlt::tensor::Shape<TI, 1, POLICY_TEST::OUTPUT_SHAPE::LAST>, false>> test_output;
    rlt::Mode<rlt::mode::Evaluation<>> mode;
    float acc = 0;
    uint64_t num_values = 0;
    for (TI batch_i = 0; batch_i < TEST_BATCH_SIZE_ACTUAL; batch_i++) {
        rlt::reset(device, policy, policy_state_test, rng);
        for (TI step_i = 0; step_i < TEST_SEQUENCE_LENGTH_ACTUAL; step_i++) {
            rlt::Tensor<rlt::tensor::Specification<T, TI, rlt::tensor::Shape<TI, 1, EXAMPLE_INPUT_DIM>, false>> batch_input;
            rlt::Tensor<rlt::tensor::Specification<T, TI, rlt::tensor::Shape<TI, 1, EXAMPLE_OUTPUT_DIM>, false>> batch_output_target;
            fseek(loaded.f, loaded.input_offset + (step_i * EXAMPLE_BATCH * EXAMPLE_INPUT_DIM + batch_i * EXAMPLE_INPUT_DIM) * sizeof(T), SEEK_SET);
            fread(batch_input._data, sizeof(T), EXAMPLE_INPUT_DIM, loaded.f);
            fseek(loaded.f, loaded.output_offset + (step_i * EXAMPLE_BATCH * EXAMPLE_OUTPUT_DIM + batch_i * EXAMPLE_OUTPUT_DIM) * sizeof(T), SEEK_SET);
            fread(batch_output_target._data, sizeof(T), EXAMPLE_OUTPUT_DIM, loaded.f);
            rlt::utils::assert_exit(device, !rlt::is_nan(device, batch_input), "input is nan");
            rlt::evaluate_step(device, policy, batch_input, policy_state_test, test_output, buffers_test, rng, mode);
            rlt::utils::assert_exit(device, !rlt::is_nan(device, test_output), "output is nan");
            for (TI action_i = 0; action_i < OUTPUT_DIM; action_i++) {
                acc += rlt::math::abs(device.math, rlt::get(device, test_output, 0, action_i) - rlt::get(device, batch_output_target, 0, action_i));
                num_values += 1;
                rlt::utils::assert_exit(device, !rlt::math::is_nan(device.math, acc), "output is nan");
            }
        }
    }
    float abs_diff = acc / num_values;
    printf("Checkpoint test diff: %.10f\n", (double)abs_diff);
    constexpr float EPSILON = 1e-5;
    if (!(abs_diff < EPSILON)) {
        printf("Checkpoint test failed with diff %.10f\n", (double)abs_diff);
        return false;
    }
    printf("Checkpoint test passed with diff %.10f\n", (double)abs_diff);
    return true;
}

static int fly(DEVICE& device, RNG& rng, POLICY& policy, const char* obs_path, const char* out_path) {
    FILE* fo = fopen(obs_path, "rb");
    if (!fo) { printf("cannot open %s\n", obs_path); return 2; }
    std::vector<float> obs;
    float record[13];
    while (fread(record, sizeof(float), 13, fo) == 13) obs.insert(obs.end(), record, record + 13);
    fclose(fo);
    static rlt::inference::applications::L2F<EXECUTOR_SPEC> executor;  // large: not on the stack
    // Raptor::init: force_sync_native from IMU_GYRO_RATEMAX, then Raptor::reset
#ifdef QP_RLTOOLS_POSIX
    executor.executor.force_sync_native = IMU_GYRO_RATEMAX / POLICY_CONTROL_FREQUENCY_TRAINING;
    executor.executor.force_sync_native_initialized = true;
#endif
    float previous_action[OUTPUT_DIM] = {0, 0, 0, 0};  // RESET_PREVIOUS_ACTION_VALUE
    rlt::reset(device, executor, policy, rng);
    std::vector<float> actions;
    TI native = 0;
    for (size_t i = 0; i < obs.size() / 13; i++) {
        const float* o = &obs[i * 13];
        rlt::inference::applications::l2f::Observation<EXECUTOR_SPEC> observation;
        rlt::inference::applications::l2f::Action<EXECUTOR_SPEC> action;
        for (TI k = 0; k < 3; k++) observation.position[k] = o[k];
        for (TI k = 0; k < 4; k++) observation.orientation[k] = o[3 + k];
        for (TI k = 0; k < 3; k++) observation.linear_velocity[k] = o[7 + k];
        for (TI k = 0; k < 3; k++) observation.angular_velocity[k] = o[10 + k];
        for (TI k = 0; k < OUTPUT_DIM; k++) observation.previous_action[k] = previous_action[k];
        uint64_t nanoseconds = (uint64_t)(1000000 + i * GYRO_INTERVAL_US) * 1000;  // hrt_abstime us * 1000
        auto status = rlt::control(device, executor, nanoseconds, policy, observation, action, rng);
        if (status.source != decltype(status.source)::CONTROL) {
            printf("gyro update %zu did not control\n", i);
            return 1;
        }
        native += status.step_type == decltype(status.step_type)::NATIVE;
        for (TI k = 0; k < OUTPUT_DIM; k++) {
            previous_action[k] = action.action[k];
            actions.push_back(action.action[k]);
        }
    }
    FILE* fa = fopen(out_path, "wb");
    if (!fa || fwrite(actions.data(), sizeof(float), actions.size(), fa) != actions.size()) { printf("cannot write %s\n", out_path); return 2; }
    fclose(fa);
    printf("flown: %zu gyro updates, %lu native steps\n", obs.size() / 13, (unsigned long)native);
    return 0;
}

// the layout RLtools' own writer gives this policy and example (as its raptor port_checkpoint does)
static int save(DEVICE& device, POLICY& policy, const Loaded& loaded, const char* out_path) {
    using EXAMPLE_IN = rlt::Tensor<rlt::tensor::Specification<T, TI, rlt::tensor::Shape<TI, 500, EXAMPLE_BATCH, EXAMPLE_INPUT_DIM>>>;
    using EXAMPLE_OUT = rlt::Tensor<rlt::tensor::Specification<T, TI, rlt::tensor::Shape<TI, 500, EXAMPLE_BATCH, EXAMPLE_OUTPUT_DIM>>>;
    EXAMPLE_IN example_input;
    EXAMPLE_OUT example_output;
    rlt::malloc(device, example_input);
    rlt::malloc(device, example_output);
#ifdef QP_RLTOOLS_POSIX
    using SPEC = rlt::persist::backends::tar::ReaderGroupSpecification<TI>;
    rlt::persist::backends::tar::ReaderGroup<SPEC> reader_group;
    reader_group.data.data = loaded.data();
    reader_group.data.size = loaded.bytes.size();
#else
    using SPEC = rlt::persist::backends::tar::ReaderGroupSpecification<TI>;
    rlt::persist::backends::tar::ReaderGroup<SPEC> reader_group;
    reader_group.data = loaded.data();
    reader_group.size = loaded.bytes.size();
#endif
    auto example_read = rlt::get_group(device, reader_group, "example");
    if (!rlt::load(device, example_input, example_read, "input") || !rlt::load(device, example_output, example_read, "output")) {
        printf("Failed to load the example\n");
        return 1;
    }
    rlt::persist::backends::tar::Writer tar_writer;
    rlt::persist::backends::tar::WriterGroup<rlt::persist::backends::tar::WriterGroupSpecification<TI, decltype(tar_writer)>> tar_group;
    tar_group.writer = &tar_writer;
    auto actor_group = rlt::create_group(device, tar_group, "actor");
    rlt::set_attribute(device, actor_group, "checkpoint_name", loaded.checkpoint_name);
    rlt::save(device, policy, actor_group);
    auto example_group = rlt::create_group(device, tar_group, "example");
    rlt::save(device, example_input, example_group, "input");
    rlt::save(device, example_output, example_group, "output");
    rlt::persist::backends::tar::finalize(device, tar_writer);
    FILE* fo = fopen(out_path, "wb");
    if (!fo || fwrite(tar_writer.buffer.data(), 1, tar_writer.buffer.size(), fo) != tar_writer.buffer.size()) { printf("cannot write %s\n", out_path); return 2; }
    fclose(fo);
    return 0;
}

int main(int argc, char** argv) {
    bool fly_mode = argc == 5 && strcmp(argv[1], "fly") == 0, save_mode = argc == 4 && strcmp(argv[1], "save") == 0;
    if (!(argc == 3 && strcmp(argv[1], "check") == 0) && !fly_mode && !save_mode) {
        printf("usage: raptor_check check POLICY_TAR | fly POLICY_TAR OBSERVATIONS_F32 ACTIONS_OUT_F32 | save POLICY_TAR OUT_TAR\n");
        return 2;
    }
    DEVICE device;
    RNG rng;
    rlt::malloc(device, rng);
    rlt::init(device, rng, 0);
    static POLICY policy;
    Loaded loaded;
    if (!load_policy(device, argv[2], policy, loaded)) return 1;
    if (!test_policy(device, rng, policy, loaded)) { printf("Checkpoint test failed\n"); return 1; }
    fclose(loaded.f);
    if (fly_mode) return fly(device, rng, policy, argv[3], argv[4]);
    if (save_mode) return save(device, policy, loaded, argv[3]);
    return 0;
}
