/* libmodbus 3.1.6 as one translation unit (its TCP server's three C files), and a backend whose
 * `send` copies the answer into memory instead of a socket, so that the count holds libmodbus's
 * own work only, as the other implementations' counts hold theirs. */
#include "modbus.c"
#include "modbus-data.c"
#include "modbus-tcp.c"

static uint8_t bench_answer[MODBUS_TCP_MAX_ADU_LENGTH];
static int bench_answer_length;
static modbus_backend_t bench_backend;

static ssize_t bench_send(modbus_t *ctx, const uint8_t *req, int req_length)
{
    (void)ctx;
    if (req_length < 0 || req_length > (int)sizeof(bench_answer))
        return -1;
    memcpy(bench_answer, req, (size_t)req_length);
    bench_answer_length = req_length;
    return req_length;
}

/* A Modbus/TCP context answering into memory. */
modbus_t *bench_new_context(void)
{
    modbus_t *ctx = modbus_new_tcp("127.0.0.1", 1502);
    if (ctx == NULL)
        return NULL;
    bench_backend = *ctx->backend;
    bench_backend.send = bench_send;
    ctx->backend = &bench_backend;
    return ctx;
}

/* The last answer: copied to `out` (room for MODBUS_TCP_MAX_ADU_LENGTH bytes); its length. */
int bench_last_answer(uint8_t *out)
{
    memcpy(out, bench_answer, (size_t)bench_answer_length);
    return bench_answer_length;
}
